"""Closed-loop metrics on hand-made records, where every figure is known."""

from dataclasses import replace

import numpy as np
import pytest

from dlmpc_ros.control.step import MODES
from dlmpc_ros.evaluation.metrics import MetricSettings, run_metrics
from dlmpc_ros.evaluation.record import RunRecord

ENVELOPE = {'K': np.array([-0.3, 0.3]), 'O_star': np.array([0.2, 0.2])}


def _record(o, k=None, latency=(1.0, 2.0, 3.0)):
    n = len(o)
    return RunRecord(round_trip=np.arange(1, n + 1), K=np.zeros(n) if k is None else k,
                     E=np.ones(n), M=np.ones(n), O=np.asarray(o, float),
                     angles=np.zeros((n, 4)), control_round_trip=np.arange(len(latency)),
                     mode=np.full(len(latency), MODES.index('outer')),
                     surrogate=np.zeros(len(latency)),
                     prediction_error=np.zeros(len(latency)),
                     iterations=np.ones(len(latency), int), latency_ms=np.array(latency))


def test_ratio_acquisition_and_locked_fraction():
    o = np.r_[np.zeros(100), np.full(800, 0.2), np.full(100, 0.05)]
    m = run_metrics(_record(o), ENVELOPE, MetricSettings(hold=50))
    assert m['mean_O'] == pytest.approx(0.165) and m['oracle_ratio'] == pytest.approx(0.825)
    assert m['acquisition_round_trips'] == 100
    assert m['locked_fraction'] == pytest.approx(800 / 900)
    assert m['step_latency_ms_median'] == 2.0
    assert m['mode_fractions'] == {'outer': 1.0}


def test_never_locked_and_blow_ups_count_as_zero():
    o = np.full(500, 0.05)
    o[10] = np.nan
    m = run_metrics(_record(o), ENVELOPE, MetricSettings(hold=50))
    assert m['acquisition_round_trips'] is None and m['locked_fraction'] == 0.0
    assert m['blown_up_round_trips'] == 1
    assert m['mean_O'] == pytest.approx(0.05 * 499 / 500)


def test_recovery_after_a_step_in_k():
    k = np.r_[np.zeros(500), np.full(500, 0.2)]
    o = np.r_[np.full(500, 0.2), np.zeros(120), np.full(380, 0.2)]
    m = run_metrics(_record(o, k), ENVELOPE, MetricSettings(hold=50))
    assert m['steps_in_K'] == 1
    assert m['recovery_round_trips'] == [120]


def test_record_round_trips_through_a_file(tmp_path):
    record = _record(np.linspace(0, 0.2, 30))
    record.meta = {'controller': 'x'}
    back = RunRecord.load(record.save(tmp_path / 'r.npz'))
    np.testing.assert_array_equal(back.O, record.O)
    assert back.meta == {'controller': 'x'} and back.mode_names == ['outer'] * 3


def test_the_estimators_own_surrogate_is_kept_and_an_older_record_without_it_loads(tmp_path):
    """A record keeps the estimator's surrogate beside the one the controller used; a file
    written before it was kept loads with NaN there (no estimate), not a KeyError."""
    from dlmpc_ros.evaluation.figures import surrogate_correlation
    k = np.linspace(-0.2, 0.2, 30)
    record = replace(_record(np.full(30, 0.1), k, latency=np.ones(30)),
                     control_round_trip=np.arange(1, 31), mode=np.full(30, MODES.index('track')),
                     surrogate=np.sin(40 * k), estimate=-3 * k)
    assert surrogate_correlation(record, tracking=True, estimator=True) == pytest.approx(1.0)
    assert surrogate_correlation(record, tracking=True) < 0.5
    path = record.save(tmp_path / 'r.npz')
    with np.load(path) as data:
        older = {name: data[name] for name in data.files if name != 'estimate'}
    np.savez(tmp_path / 'old.npz', **older)
    back = RunRecord.load(tmp_path / 'old.npz')
    assert back.estimate.shape == (30,) and np.isnan(back.estimate).all()
    assert surrogate_correlation(back, tracking=True, estimator=True) is None
    np.testing.assert_array_equal(RunRecord.load(path).estimate, record.estimate)


def test_round_trips_without_k_are_left_out_and_a_run_without_k_gets_measured_metrics():
    record = _record(np.full(100, 0.1), np.zeros(100))
    partial = replace(record, K=np.r_[np.zeros(90), np.full(10, np.nan)],
                      O=np.r_[np.full(90, 0.1), np.zeros(10)])
    m = run_metrics(partial, ENVELOPE)
    assert m['round_trips'] == 90 and m['round_trips_without_K'] == 10
    assert m['mean_O'] == pytest.approx(0.1)
    none = run_metrics(replace(record, K=np.full(100, np.nan)), ENVELOPE)
    assert none['mean_O'] == pytest.approx(0.1) and none['round_trips_without_K'] == 100
    assert none['oracle_ratio'] is None and none['locked_fraction'] is None


def test_seed_summary_and_ratio_to_the_oracle_controller():
    from dlmpc_ros.evaluation.report import add_oracle_controller_ratio, seed_summary

    runs = [{'scenario': 'steps', 'seed': seed, 'controller': name,
             'metrics': {'mean_O': mean_o, 'oracle_ratio': mean_o / 0.2}}
            for seed, name, mean_o in ((1, 'dlmpc', 0.1), (1, 'oracle', 0.2),
                                       (2, 'dlmpc', 0.15), (2, 'oracle', 0.16))]
    add_oracle_controller_ratio(runs)
    assert [r['metrics']['oracle_controller_ratio'] for r in runs] == \
        pytest.approx([0.5, 1.0, 0.9375, 1.0])
    table = seed_summary(runs)
    assert table.splitlines()[0] == '| scenario | dlmpc | oracle |'
    assert table.splitlines()[2] == '| steps | 0.625 (0.500-0.750) | 0.900 (0.800-1.000) |'
