"""The package as ROS users install it, and the core without ROS."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXECUTABLES = ('laser_sim', 'drift_injector', 'bringup', 'dlmpc-sim')


def test_colcon_style_install_puts_executables_where_ros2_run_looks(tmp_path):
    """Run the setup.py commands colcon's ament_python build runs; check the layout."""
    prefix = tmp_path / 'install'
    build = tmp_path / 'build'
    build.mkdir()
    proc = subprocess.run(
        [sys.executable, 'setup.py', 'egg_info', '--egg-base', str(build),
         'build', '--build-base', str(build / 'build'),
         'install', '--prefix', str(prefix), '--record', str(build / 'record.txt'),
         '--single-version-externally-managed'],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    for exe in EXECUTABLES:
        assert (prefix / 'lib' / 'dlmpc_ros' / exe).is_file(), exe
        assert not (prefix / 'bin' / exe).exists()
    share = prefix / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'dlmpc_ros').is_file()
    assert (share / 'dlmpc_ros' / 'package.xml').is_file()
    assert {p.name for p in (share / 'dlmpc_ros' / 'config').iterdir()} >= {
        'laser_sim.yaml', 'drift_injector.yaml', 'fastdds_loopback.xml'}


def _fresh_python(code: str) -> subprocess.CompletedProcess:
    """``code`` run by a new interpreter in the repository (nothing imported before it)."""
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def test_core_runs_without_rclpy():
    code = ('import sys; sys.modules["rclpy"] = None\n'
            'from dlmpc_ros.core.cavity import Cavity\n'
            'from dlmpc_ros.core.drift import make_scenario\n'
            'from dlmpc_ros.cli.sim import main\n'
            'r = Cavity(birefringence=make_scenario("chirp")(100)).run(2)\n'
            'assert r.finite.all()\n'
            'print("ok")')
    proc = _fresh_python(code)
    assert proc.returncode == 0 and proc.stdout.strip() == 'ok', proc.stderr


def test_nodes_import_only_what_their_start_needs():
    """Start-up time on a small machine is the nodes' imports: the drift injector and the
    bringup load no numba (a random walk is a plain loop), and the DL-MPC node's module
    no torch (its node imports it once the node exists, so that discovery overlaps); a
    node's age, which its ready line reports, is the seconds since its process started."""
    code = ('import sys\n'
            'import dlmpc_ros.nodes.drift_injector_node, dlmpc_ros.bringup\n'
            'from dlmpc_ros.core.drift import make_scenario\n'
            'make_scenario("random_walk", seed=1)(70000)\n'
            'light = "numba" not in sys.modules\n'
            'import dlmpc_ros.nodes.mpc_controller_node\n'
            'from dlmpc_ros.ros.params import process_age\n'
            'print(light, "torch" in sys.modules, 0 < process_age() < 120)')
    proc = _fresh_python(code)
    assert proc.stdout.split() == ['True', 'False', 'True'], proc.stderr[-2000:]
