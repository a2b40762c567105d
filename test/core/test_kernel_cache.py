"""A kernel compiled in this process computes what the same kernel loaded from numba's
on-disk cache computes (bit for bit): the first process on a machine must not differ
from the others, nor serial runs from those on Dask workers. (The serial kernel only: the
thread-parallel one runs the same per-laser code, and compiling it too doubles the cost.)"""

import os
import subprocess
import sys

SCRIPT = '''
import hashlib, numpy as np
from dlmpc_ros.core.cavity import Cavity
cavity = Cavity(angles=np.array([-0.39, -0.25, 0.52, -0.14]), birefringence=0.1)
print(hashlib.sha1(np.ascontiguousarray(cavity.run(40).E).tobytes()).hexdigest())
'''


def test_a_freshly_compiled_kernel_equals_the_cached_one(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    runs = [subprocess.run([sys.executable, '-c', SCRIPT], env=env, capture_output=True,
                           text=True, timeout=600, check=True).stdout.split()
            for _ in range(2)]
    assert any(tmp_path.rglob('*.nbi')), 'the first run wrote no cache'
    assert len(runs[0]) == 1 and runs[0] == runs[1]
