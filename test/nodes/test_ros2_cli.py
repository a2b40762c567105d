"""What a ROS user types, with the real ros2 command line (``make ros2cli`` installs it and
colcon into .venv; a ROS 2 install has them): a colcon install of the package, ``ros2 pkg
executables``, ``ros2 run dlmpc_ros laser_sim``, ``ros2 topic echo``, ``ros2 param
describe`` and ``set`` (refused out of range) and ``/diagnostics``. Skipped, saying why,
where ``ros2`` or ``colcon`` is missing."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent


def _tool(name: str) -> str | None:
    local = BIN / name
    return str(local) if local.exists() else shutil.which(name)


ROS2, COLCON = _tool('ros2'), _tool('colcon')
pytestmark = pytest.mark.skipif(
    ROS2 is None or COLCON is None,
    reason='no ros2 command line or colcon here (make ros2cli installs them into .venv)')


@pytest.fixture(scope='module')
def install(tmp_path_factory) -> Path:
    """A colcon install of this package (built out of the source tree)."""
    base = tmp_path_factory.mktemp('colcon')
    env = {**os.environ, 'PATH': f'{BIN}{os.pathsep}{os.environ.get("PATH", "")}'}
    proc = subprocess.run([COLCON, '--log-base', str(base / 'log'), 'build', '--base-paths',
                           str(ROOT), '--build-base', str(base / 'build'), '--install-base',
                           str(base / 'install'), '--packages-select', 'dlmpc_ros'],
                          cwd=base, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return base / 'install'


def _sourced(install: Path, command: str) -> list[str]:
    return ['bash', '-c', f'. {shlex.quote(str(install / "setup.bash"))} && {command}']


def _until(install: Path, env: dict, command: str, wanted: str, timeout: float = 60.0) -> str:
    """Run ``command`` until its output holds ``wanted`` (discovery takes a while; on a
    loaded machine one try may hang past its 30 s, and the next is made)."""
    deadline, out = time.monotonic() + timeout, ''
    while time.monotonic() < deadline:
        try:
            proc = subprocess.run(_sourced(install, command), env=env, capture_output=True,
                                  text=True, timeout=30)
        except subprocess.TimeoutExpired as hung:
            out = f'(timed out after 30 s) {hung.stdout or ""}{hung.stderr or ""}'
            continue
        out = proc.stdout + proc.stderr
        if wanted in out:
            return out
        time.sleep(0.5)
    raise AssertionError(f'{command!r} never printed {wanted!r}; last output:\n{out}')


def test_a_ros_user_runs_echoes_describes_and_sets(install, ros_env, tmp_path):
    env = {**ros_env, 'PATH': f'{BIN}{os.pathsep}{ros_env.get("PATH", "")}'}
    executables = _until(install, env, 'ros2 pkg executables dlmpc_ros', 'laser_sim')
    for name in ('laser_sim', 'drift_injector', 'vae_estimator', 'mpc_controller',
                 'baseline_controller', 'recorder'):
        assert f'dlmpc_ros {name}' in executables
    log = open(tmp_path / 'laser.log', 'wb')
    laser = subprocess.Popen(_sourced(install, 'exec ros2 run dlmpc_ros laser_sim --ros-args '
                                      '-p round_trips_per_second:=100.0 '
                                      '-p wait_for_subscribers:=0'),
                             env=env, stdout=log, stderr=subprocess.STDOUT,
                             start_new_session=True)
    try:
        echo = _until(install, env, 'ros2 topic echo /laser/objective std_msgs/msg/'
                      'Float64MultiArray --once --no-daemon --qos-reliability reliable', 'data:')
        assert 'label: O' in echo
        describe = _until(install, env, 'ros2 param describe /laser_sim pump --no-daemon',
                          'Min value')
        assert 'Max value' in describe and 'pump' in describe
        refused = _until(install, env, 'ros2 param set /laser_sim pump -1.0 --no-daemon',
                         'Setting parameter failed')
        assert 'pump' in refused
        accepted = _until(install, env, 'ros2 param set /laser_sim pump 1.5 --no-daemon',
                          'Set parameter successful')
        assert accepted
        health = _until(install, env, 'ros2 topic echo /diagnostics '
                        'diagnostic_msgs/msg/DiagnosticArray --once --no-daemon '
                        '--qos-reliability reliable',
                        'name: laser_sim')
        assert 'round_trip' in health
    finally:
        os.killpg(laser.pid, signal.SIGINT)
        try:
            code = laser.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(laser.pid, signal.SIGKILL)
            code = laser.wait()
        log.close()
    text = (tmp_path / 'laser.log').read_text(errors='replace')
    assert code == 0 and 'Traceback' not in text, text[-2000:]
