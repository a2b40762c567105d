"""A plugged-in controller in dlmpc-evaluate: fast runs on Dask workers (the spec and
the entry point resolved there), the lock benchmark, and a bad spec stopped at start.
(The node graph: test/nodes/test_bringup.py and test_startup_errors.py.)"""

from __future__ import annotations

import json

import numpy as np

from dlmpc_ros.cli.evaluate import main as evaluate
from dlmpc_ros.control.step import MODES
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.paths import models_dir
from test.control.test_plugins import install

EXAMPLE = 'dlmpc_ros.examples.hill_climber:make'


def test_fast_runs_on_workers_take_a_spec_and_an_installed_name(tmp_path, monkeypatch):
    site = install(tmp_path / 'site', 'mylab', {'mylab_hill': EXAMPLE})
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setenv('PYTHONPATH', str(site))  # where the workers find the package
    out = tmp_path / 'eval'
    assert evaluate(['--fast', '--controller', EXAMPLE, '--controller', 'mylab_hill',
                     '--round-trips', '200', '--workers', '2', '--models-dir',
                     str(models_dir()), '--out', str(out)]) == 0
    runs = json.loads((out / 'metrics.json').read_text())['runs']
    assert sorted(r['controller'] for r in runs) == sorted([EXAMPLE, 'mylab_hill'])
    spec = RunRecord.load(out / 'sinusoidal-s1-dlmpc_ros.examples.hill_climber-make'
                          / 'record.npz')
    name = RunRecord.load(out / 'sinusoidal-s1-mylab_hill' / 'record.npz')
    assert set(spec.mode.tolist()) == {MODES.index('custom')}
    np.testing.assert_array_equal(spec.angles, name.angles)  # one controller, two names


def test_the_lock_benchmark_runs_a_plugged_in_controller(tmp_path):
    out = tmp_path / 'lock'
    assert evaluate(['--benchmark', 'lock', '--starts', '2', '--budget', '200',
                     '--controller', EXAMPLE, '--workers', '1', '--models-dir',
                     str(models_dir()), '--out', str(out)]) == 0
    result = json.loads((out / 'lock.json').read_text())[EXAMPLE]
    assert result['starts'] == 2 and len(result['round_trips_to_lock']) == 2


def test_a_bad_spec_stops_dlmpc_evaluate_at_start_in_one_line(tmp_path, capsys):
    assert evaluate(['--fast', '--controller', 'esc', '--controller',
                     'test.control.plugin_examples:raises', '--out', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'Traceback' not in err
    assert err.startswith("dlmpc-evaluate: controller 'test.control.plugin_examples:raises': "
                          'its factory raised FileNotFoundError')
    assert not list(tmp_path.glob('*-esc'))  # nothing ran
