"""The teardown deadline ends a process that Python cannot run in, with the given code.

Fast DDS's participant destruction once spun for good while holding the GIL
(``dlmpc_ros/ros/teardown.py``); a C call that holds the GIL (``sleep`` through
``ctypes.PyDLL``) stands in for it here.
"""

import os
import subprocess
import sys
import time

import pytest

from dlmpc_ros.ros.teardown import exit_after

HELD = """
import ctypes, sys
from dlmpc_ros.ros.teardown import exit_after
print('printed before', end='')  # buffered: a pipe
with exit_after(float(sys.argv[1]), int(sys.argv[2])) as armed:
    assert armed
    ctypes.PyDLL(None).sleep(int(sys.argv[3]))  # a C call that keeps the GIL
if len(sys.argv) > 4:  # the deadline is off once the block is left
    ctypes.PyDLL(None).sleep(int(sys.argv[4]))
sys.exit(9)
"""


def _run(seconds: float, code: int, hold: int, *after: int) -> tuple[int, float]:
    start = time.monotonic()
    done = subprocess.run([sys.executable, '-c', HELD, str(seconds), str(code), str(hold),
                           *map(str, after)],
                          timeout=60, capture_output=True, text=True,
                          env={k: v for k, v in os.environ.items() if k != 'PYTHONUNBUFFERED'})
    assert not done.stderr, done.stderr
    assert done.stdout == 'printed before', done.stdout  # flushed, though _exit skips it
    return done.returncode, time.monotonic() - start


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='glibc timers')
def test_a_process_stuck_in_c_holding_the_gil_ends_with_the_code_given():
    code, took = _run(0.3, 3, 30)
    assert code == 3
    assert took < 20  # not the 30 s of the stuck call
    assert _run(0.3, 0, 30)[0] == 0


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='glibc timers')
def test_a_block_left_in_time_keeps_the_process_and_its_own_code():
    assert _run(20, 3, 0)[0] == 9
    assert _run(0.3, 3, 0, 1)[0] == 9  # 1 s after the block, past its 0.3 s


@pytest.mark.parametrize('seconds, code', [(0, 0), (-1, 0), (float('nan'), 0), (1, 256),
                                           (1, -1)])
def test_a_deadline_it_cannot_keep_is_refused(seconds, code):
    with pytest.raises(ValueError, match='exit_after'), exit_after(seconds, code):
        pass
