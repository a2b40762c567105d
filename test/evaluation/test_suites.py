"""The stress suite: its conditions, its table and envelope check, a smoke run, and the
lock benchmark's fixed K."""

import json

import numpy as np
import pytest

from dlmpc_ros.cli.evaluate import _run_dir, Plant, main as evaluate_main, parse_args, run_specs
from dlmpc_ros.core.bench import BENCH_PRESETS
from dlmpc_ros.evaluation.lock_benchmark import LockSpec, LockTask, run_starts
from dlmpc_ros.evaluation.presets import preset_scenario
from dlmpc_ros.evaluation.suites import (STRESS_DRIFTS, Condition, over_envelope,
                                         stress_conditions, suite_cells, write_suite)
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.paths import models_dir


def test_the_stress_suite_is_every_drift_on_every_bench_with_its_own_run_folders(tmp_path):
    conditions = stress_conditions()
    assert len(conditions) == 16
    assert conditions['sin6k-servo3'].bench == BENCH_PRESETS['servo-3']
    assert conditions['walk-servo6'].bench == BENCH_PRESETS['servo-6']
    assert conditions['steps-noise1'].bench == {'detector_noise': 0.01}
    assert conditions['sin20k-ideal'].bench == {}
    assert conditions['sin20k-ideal'].settings == {'amplitude': 0.3, 'period': 20000.0}
    args = parse_args(['--suite', 'stress', '--out', str(tmp_path)])
    assert args.fast and args.seed == [1, 2, 3]
    assert args.controller == ['dlmpc', 'esc', 'ga', 'passive', 'fixed_best']
    specs = run_specs(args)
    assert len(specs) == 16 * 3 * 5
    folders = {_run_dir(tmp_path, Plant('nominal', {}), s, False) for s in specs}
    assert len(folders) == len(specs)  # two sinusoids, one scenario name: apart
    for bad in (['--scenario', 'steps'], ['--bench', 'lab'], ['--condition', 'sin6k'],
                ['--measurement-noise', '0.01'], ['--benchmark', 'lock']):
        with pytest.raises(SystemExit):
            parse_args(['--suite', 'stress', *bad, '--out', str(tmp_path)])
    with pytest.raises(ValueError, match='name'):
        Condition('a b', 'steps')


def test_the_random_walk_reaches_both_ends_of_the_k_range_within_a_run():
    scenario, settings = STRESS_DRIFTS['walk']
    for seed in (1, 2, 3):
        k = preset_scenario(scenario, seed, settings)(np.arange(20001))
        assert k.min() <= -0.29 and k.max() >= 0.29, seed


def _run(plant: str, condition: str, seed: int, controller: str, ratio: float) -> dict:
    return {'plant': plant, 'scenario': 'sinusoidal', 'condition': condition, 'seed': seed,
            'controller': controller, 'metrics': {'oracle_ratio': ratio}}


def test_the_table_averages_over_seeds_and_lists_every_run_above_its_envelope(tmp_path):
    runs = [_run('nominal', 'sin6k-ideal', 1, 'dlmpc', 0.9),
            _run('nominal', 'sin6k-ideal', 2, 'dlmpc', 0.8),
            _run('nominal', 'sin20k-ideal', 1, 'dlmpc', 0.95),
            _run('family-3', 'sin20k-ideal', 3, 'passive', 1.013),
            _run('family-3', 'sin20k-ideal', 1, 'passive', 1.0)]
    cells = suite_cells(runs)
    assert cells[0] == {'plant': 'nominal', 'condition': 'sin6k-ideal', 'controller': 'dlmpc',
                        'seeds': 2, 'mean': pytest.approx(0.85), 'min': 0.8, 'max': 0.9}
    assert over_envelope(runs) == [{'plant': 'family-3', 'condition': 'sin20k-ideal',
                                    'seed': 3, 'controller': 'passive',
                                    'oracle_ratio': 1.013}]
    conditions = stress_conditions()
    write_suite(tmp_path, 'stress', conditions, runs, {'nominal': {}}, {'seeds': [1, 2, 3]})
    text = (tmp_path / 'stress.md').read_text()
    assert '| nominal | sin6k-ideal | 0.850 (0.800-0.900) | - |' in text
    assert '| family-3 | sin20k-ideal | 3 | passive | 1.013 |' in text
    saved = json.loads((tmp_path / 'stress.json').read_text())
    assert len(saved['runs']) == 5 and len(saved['over_envelope']) == 1
    write_suite(tmp_path, 'stress', conditions, runs[:3], {'nominal': {}}, {})
    assert 'No run exceeds 1' in (tmp_path / 'stress.md').read_text()


def test_two_conditions_of_one_scenario_run_apart_and_resume(tmp_path, capsys):
    argv = ['--suite', 'stress', '--condition', 'sin6k-ideal', '--condition',
            'sin20k-servo3', '--controller', 'passive', '--seed', '1', '--round-trips', '200',
            '--workers', '1', '--out', str(tmp_path)]
    assert evaluate_main(argv) == 0
    saved = json.loads((tmp_path / 'stress.json').read_text())
    assert [r['condition'] for r in saved['runs']] == ['sin6k-ideal', 'sin20k-servo3']
    ratios = [r['oracle_ratio'] for r in saved['runs']]
    assert ratios[0] != ratios[1] and all(0 < r < 1 for r in ratios)
    meta = json.loads((tmp_path / 'sin20k-servo3-s1-passive' / 'metrics.json').read_text())
    assert meta['condition'] == 'sin20k-servo3' and meta['bench']['servo_lag'] == 3
    capsys.readouterr()
    assert evaluate_main([*argv, '--resume']) == 0
    assert '2 of 2 runs already in' in capsys.readouterr().out


def test_the_lock_benchmark_can_hold_every_start_at_one_k():
    with pytest.raises(ValueError, match='LockSpec.k'):
        LockSpec('passive', k=0.4)
    tables = load_baselines(models_dir() / 'oracle.npz')
    spec = LockSpec('passive', starts=2, budget=100, k=-0.3)
    starts = run_starts(LockTask(spec, (0, 1), str(models_dir()), tables['K'],
                                 tables['O_star']))
    assert [s['K'] for s in starts] == [-0.3, -0.3]
