"""``bench/tune_baselines.py``: the Optuna tuning of the GA and ESC baselines, on a tiny
case (one plant, one cold start, a 300-round-trip budget, a 200-round-trip drift run).

Its lock runner must be the lock benchmark's: with the shipped settings it gives the
same starts as :func:`dlmpc_ros.evaluation.lock_benchmark.run_starts`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from test.bench.test_variants_parse import _bench_module

ROOT = Path(__file__).resolve().parents[2]
TINY = ['--plants', 'nominal', '--starts', '1', '--budget', '300',
        '--drift-round-trips', '200', '--trials', '2']
TRIAL_KEYS = {'number', 'state', 'value', 'shipped', 'params', 'settings', 'values',
              'wall_s', 'started'}


def _tuner():
    return _bench_module('tune_baselines')


@pytest.mark.parametrize('method, extra', [('esc', []), ('ga', ['--settle-round-trips', '30'])])
def test_two_trials_write_the_record(tmp_path, method, extra, capsys):
    tb = _tuner()
    assert tb.main(['--method', method, *TINY, *extra, '--out', str(tmp_path)]) == 0
    record = json.loads((tmp_path / f'{method}.json').read_text())
    assert {'method', 'command', 'optuna', 'sampler', 'settings', 'objective', 'plants',
            'trials', 'best', 'shipped', 'wall_s_per_complete_trial'} <= set(record)
    assert record['method'] == method and len(record['trials']) == 2
    for trial in record['trials']:
        assert TRIAL_KEYS <= set(trial) and trial['state'] == 'COMPLETE'
        assert trial['wall_s'] > 0 and set(trial['values']['plants']) == {'nominal'}
        values = trial['values']
        assert values['objective'] == pytest.approx(
            0.5 * values['lock_score'] + 0.5 * values['drift_ratio'])
    shipped = record['trials'][0]
    assert shipped['shipped'] and record['shipped']['number'] == 0
    assert record['best']['value'] == max(t['value'] for t in record['trials'])
    if method == 'ga':  # the shipped trial runs the shipped GA, dwell included
        from dataclasses import asdict

        from dlmpc_ros.control.ga import GAConfig
        assert shipped['settings'] == asdict(GAConfig())
        assert record['settle_round_trips'] == 30
    else:
        from dlmpc_ros.control.esc import ESCConfig
        assert tb.esc_settings(shipped['params']) == ESCConfig()
    summary = (tmp_path / f'{method}.md').read_text()
    assert 'smoke run' in summary and '(shipped)' in summary
    assert '[2/2]' in capsys.readouterr().out
    # --confirm runs the study's shipped and best settings again, on other starts
    study = tmp_path / f'{method}.json'
    assert tb.main(['--method', method, *TINY, '--lock-seed', '2', '--confirm', str(study),
                    '--out', str(tmp_path)]) == 0
    confirmed = json.loads((tmp_path / f'{method}_confirm.json').read_text())
    assert set(confirmed['rows']) == {'shipped', 'best'}
    for name, row in confirmed['rows'].items():
        assert row['settings'] == record[name]['settings']
        assert set(row['values']['plants']) == {'nominal'}
    assert '| shipped (trial 0) |' in (tmp_path / f'{method}_confirm.md').read_text()


def test_the_lock_runner_is_the_lock_benchmarks():
    from dlmpc_ros.control.esc import ESCConfig
    from dlmpc_ros.control.ga import GAConfig
    from dlmpc_ros.evaluation.lock_benchmark import LockSpec, LockTask, run_starts
    from dlmpc_ros.learning.tables import load_baselines
    tb = _tuner()
    tables = load_baselines(ROOT / 'models' / 'oracle.npz')
    for method, config in (('ga', GAConfig()), ('esc', ESCConfig())):
        spec = LockSpec(method, starts=1, budget=300, seed=1)
        ours = tb.lock_starts(tb.builder(method, config), spec, tables)
        theirs = run_starts(LockTask(spec, (0,), str(ROOT / 'models'), tables['K'],
                                     tables['O_star']))
        assert ours == theirs


def test_a_trial_reports_after_each_plant_but_the_last():
    from dlmpc_ros.control.esc import ESCConfig
    from dlmpc_ros.learning.tables import load_baselines
    tb = _tuner()
    args = tb.parse_args(['--method', 'esc', *TINY])
    nominal = tb.resolve_plant('nominal', load_baselines(ROOT / 'models' / 'oracle.npz'))
    twin = tb.Plant('twin', nominal.parameters, nominal.envelope)
    reports = []
    values = tb.evaluate(args, ESCConfig(), [nominal, twin],
                         lambda step, value, per_plant: reports.append((step, value,
                                                                        list(per_plant))))
    assert reports == [(0, values['plants']['nominal']['objective'], ['nominal'])]
    assert values['plants']['twin'] == {**values['plants']['nominal'],
                                        'wall_s': values['plants']['twin']['wall_s']}


def test_the_search_spaces_hold_valid_settings():
    from dlmpc_ros.control.esc import ESCConfig
    tb = _tuner()
    for frequencies in tb.FREQUENCY_SETS.values():
        ESCConfig(frequencies=frequencies)
    assert tb.FREQUENCY_SETS['shipped'] == tuple(ESCConfig().frequencies)
    from dlmpc_ros.control.ga import GAConfig
    for settle in (1.0, 10.0, 40.0):
        assert tb.ga_settings(tb.ga_shipped(settle), settle).dwell == GAConfig().dwell
    slow = {**tb.ga_shipped(10.0), 'dwell_factor': 2.0}
    assert tb.ga_settings(slow, 100.0).dwell == 20


def test_settle_time_of_a_tiny_batch():
    from dlmpc_ros.learning.tables import load_baselines
    tb = _tuner()
    tables = load_baselines(ROOT / 'models' / 'oracle.npz')
    plant = tb.resolve_plant('nominal', tables)
    settle = tb.settle_time(plant, lasers=2, warm=20, window=60, tail=10)
    assert settle['lasers'] == 2 and 0 <= settle['round_trips'] <= 60
    assert len(settle['to_best_angles']) + len(settle['to_random_angles']) == 2
    assert np.isfinite(settle['median_round_trips'])


@pytest.mark.parametrize('argv, message', [
    (['--method', 'ga', '--plants', '101'], 'held out'),
    (['--method', 'ga', '--plants', 'nominal', '9'], 'not a development plant'),
    (['--method', 'esc', '--budget', '200'], 'must exceed the lock hold'),
    (['--method', 'esc', '--trials', '0'], '--trials must be >= 1'),
    (['--method', 'esc', '--lock-weight', '1.5'], '--lock-weight must be in [0, 1]'),
    (['--method', 'esc', '--drift-round-trips', '0'], 'give --lock-weight 1'),
    (['--method', 'esc', '--settle-round-trips', '30'], 'esc has none'),
    (['--method', 'esc', '--drift-scenario', 'wobble'], "'wobble'"),
    (['--method', 'bo'], "invalid choice: 'bo'"),
])
def test_bad_arguments_say_what_is_wrong(argv, message, capsys):
    with pytest.raises(SystemExit) as err:
        _tuner().parse_args(argv)
    assert err.value.code == 2
    assert message in capsys.readouterr().err
