"""The demo's figure and summary from a run's CSV files: the run beside the uncontrolled
laser on the same K(t) and the envelope."""

import csv

import numpy as np

from dlmpc_ros.control.baselines import FixedBestController, PassiveController
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import make_scenario
from dlmpc_ros.evaluation.closed_loop import run_closed_loop
from dlmpc_ros.evaluation.demo import RecordedDrift, demo_report, uncontrolled
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.paths import models_dir
from dlmpc_ros.recording.run_csv import DECISION_FIELDS, RUN_FIELDS, decisions_path

START = np.array([-0.39, -0.25, 0.52, -0.14])


def _write_csvs(record, path):
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(RUN_FIELDS)
        for i, r in enumerate(record.round_trip):
            writer.writerow([r, record.E[i], record.M[i], record.O[i], record.E[i] ** 2, 1.0,
                             *record.angles[i], record.K[i]])
    with open(decisions_path(path), 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(DECISION_FIELDS)
        for i, r in enumerate(record.control_round_trip):
            writer.writerow([r, record.mode[i], -1.0, 0, record.latency_ms[i], 0.0, 0.0, -1.0,
                             0.0])


def test_the_uncontrolled_laser_runs_the_recorded_drift_from_the_recorded_start():
    tables = load_baselines(models_dir() / 'oracle.npz')
    run = run_closed_loop(FixedBestController(tables['fixed_best_angles']),
                          make_scenario('sinusoidal', amplitude=0.2, period=300.0), 300, 10,
                          START)
    held = uncontrolled(run, CavityConfig(), 10)
    np.testing.assert_array_equal(held.K, run.K)
    np.testing.assert_array_equal(held.angles, np.tile(START, (300, 1)))
    direct = run_closed_loop(PassiveController(START), RecordedDrift(run), 300, 10, START)
    np.testing.assert_array_equal(held.O, direct.O)


def test_demo_report_draws_the_figure_and_says_how_close_to_the_envelope(tmp_path):
    tables = load_baselines(models_dir() / 'oracle.npz')
    run = run_closed_loop(FixedBestController(tables['fixed_best_angles']),
                          make_scenario('sinusoidal', amplitude=0.2, period=300.0), 300, 10,
                          START)
    _write_csvs(run, tmp_path / 'run.csv')
    line = demo_report(tmp_path / 'run.csv', tmp_path / 'run.png', 'fixed_best',
                       CavityConfig(), 10, tables)
    assert line.startswith('fixed_best: oracle ratio ') and 'uncontrolled: oracle ratio' in line
    assert (tmp_path / 'run.png').stat().st_size > 20_000
    plain = demo_report(tmp_path / 'run.csv', tmp_path / 'plain.png', 'fixed_best',
                        CavityConfig(pump=1.7), 10, None)
    assert 'no envelope for this plant' in plain
