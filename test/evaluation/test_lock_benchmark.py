"""The auto-mode-locking benchmark: its metrics, and a tiny real run."""

import json

import numpy as np
import pytest

from dlmpc_ros.cli.evaluate import main as evaluate
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.evaluation.lock_benchmark import (LockSpec, LockTask, lock_metrics, run_starts,
                                                 start_conditions, sweep_metrics,
                                                 within_budget)
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.paths import models_dir


def test_lock_metrics_count_failures_as_longer_than_any_start():
    spec = LockSpec('esc', starts=10)
    times = [100, 200, 300, 400, 500, 600, 700, 800, 900, None]
    starts = [{'locked': t is not None, 'round_trips': t} for t in times]
    m = lock_metrics(starts, spec)
    assert m['success_rate'] == pytest.approx(0.9) and m['locked'] == 9
    assert m['median_round_trips'] == 500 and m['median_control_periods'] == 50
    assert m['p90_round_trips'] == 900
    m = lock_metrics(starts[:8] + [starts[9], starts[9]], spec)  # 80 % locked
    assert m['p90_round_trips'] is None
    assert lock_metrics([], spec)['success_rate'] == 0


def test_starts_are_seeded_and_the_same_for_every_controller():
    a, b = start_conditions(0, 3), start_conditions(0, 3)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1:] == b[1:] and -0.3 <= a[1] <= 0.3
    assert start_conditions(0, 4)[2] != a[2]
    with pytest.raises(ValueError, match='drift'):
        LockSpec('esc', drift='fast')
    with pytest.raises(ValueError, match='physical'):
        LockSpec('esc', plant={'points': 128})


def test_a_tiny_benchmark_runs_cold_starts_from_noise_and_repeats_itself():
    tables = load_baselines(models_dir() / 'oracle.npz')
    spec = LockSpec('fixed_best', starts=3, budget=400, hold_periods=5)
    task = LockTask(spec, (0, 1, 2), str(models_dir()), tables['K'], tables['O_star'])
    first, again = run_starts(task), run_starts(task)
    assert first == again
    assert [s['index'] for s in first] == [0, 1, 2]
    for s in first:
        assert s['locked'] == (s['round_trips'] is not None)
        assert s['round_trips'] is None or 0 <= s['round_trips'] <= 400 - 50


def test_a_task_runs_the_dl_mpc_with_the_settings_it_is_given():
    """The variant runner's lock mode hands its settings through the task: without the
    acquisition scan, a start that the shipped DL-MPC locks by scanning stays unlocked
    (start 9 of the models of 2026-12-05; start 0 locks without the scan too)."""
    tables = load_baselines(models_dir() / 'oracle.npz')
    spec = LockSpec('dlmpc', starts=2, budget=400, hold_periods=5)

    def locked(config: DLMPCConfig | None) -> list[bool]:
        task = LockTask(spec, (0, 9), str(models_dir()), tables['K'], tables['O_star'], config)
        return [s['locked'] for s in run_starts(task)]

    assert locked(None) == [True, True]
    assert locked(DLMPCConfig(acquisition=None))[1] is False  # start 9 needs the scan


def test_a_budget_sweep_scores_each_budget_as_a_run_of_that_budget_would():
    """fixed_best locks starts 8, 4 and 0 at round trips 47, 57 and 63 (a hold of 50): run
    once at 200, each smaller budget derived from the times to lock is what a run of that
    budget finds, to the round trip (113 = 63 + 50 holds start 0's lock, 112 does not)."""
    tables = load_baselines(models_dir() / 'oracle.npz')

    def run(budget: int) -> list[dict]:
        spec = LockSpec('fixed_best', starts=3, budget=budget, hold_periods=5)
        return run_starts(LockTask(spec, (8, 4, 0), str(models_dir()), tables['K'],
                                   tables['O_star']))

    spec = LockSpec('fixed_best', starts=3, budget=200, hold_periods=5)
    longest = run(200)
    assert [s['round_trips'] for s in longest] == [47, 57, 63]
    for budget in (96, 100, 112, 113):
        assert within_budget(longest, budget, spec) == run(budget), budget
    sweep = sweep_metrics(longest, spec, [200, 100, 112])
    assert list(sweep) == ['100', '112', '200']
    assert [sweep[b]['locked'] for b in sweep] == [1, 2, 3]
    assert sweep['112']['median_round_trips'] == 52 and sweep['112']['p90_round_trips'] is None
    assert sweep['200']['p90_control_periods'] == 6.3
    with pytest.raises(ValueError, match='budget'):
        within_budget(longest, 201, spec)


def test_dlmpc_evaluate_sweeps_budgets_with_the_smallest_as_the_headline(tmp_path):
    out = tmp_path / 'lock'
    assert evaluate(['--benchmark', 'lock', '--starts', '2', '--budget', '300', '--budget',
                     '150', '--controller', 'bo', '--workers', '1', '--models-dir',
                     str(models_dir()), '--out', str(out)]) == 0
    summary = json.loads((out / 'lock.json').read_text())
    assert summary['settings']['budget'] == 150 and summary['settings']['budgets'] == [150, 300]
    bo = summary['bo']
    assert set(bo['budgets']) == {'150', '300'}
    assert {k: v for k, v in bo.items() if k != 'budgets'} == bo['budgets']['150']
    table = (out / 'lock.md').read_text()
    assert 'Budget sweep' in table and '| nominal | bo | 300 |' in table
    assert (out / 'lock.png').stat().st_size > 0
