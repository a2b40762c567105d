"""The auto-mode-locking benchmark: its metrics, and a tiny real run."""

import numpy as np
import pytest

from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.evaluation.lock_benchmark import (LockSpec, LockTask, lock_metrics, run_starts,
                                                 start_conditions)
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
    (start 3; start 0 locks without the scan too since the numbers of 2026-12-04)."""
    tables = load_baselines(models_dir() / 'oracle.npz')
    spec = LockSpec('dlmpc', starts=2, budget=400, hold_periods=5)

    def locked(config: DLMPCConfig | None) -> list[bool]:
        task = LockTask(spec, (0, 3), str(models_dir()), tables['K'], tables['O_star'], config)
        return [s['locked'] for s in run_starts(task)]

    assert locked(None) == [True, True]
    assert locked(DLMPCConfig(acquisition=None))[1] is False  # start 3 needs the scan
