"""A closed-loop run through the real node graph: the bringup as a subprocess, its CSV
files read back into a :class:`~dlmpc_ros.evaluation.record.RunRecord` (no rclpy here)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from dlmpc_ros.control.step import MEASUREMENT_ROUND_TRIPS, MODES
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.recording.run_csv import read_decisions_csv, read_run_csv


def record_from_csv(run_csv: Path, meta: dict | None = None) -> RunRecord:
    """The record of a bringup run from ``run.csv`` and ``run.controller.csv``."""
    rows = read_run_csv(run_csv)
    decisions = read_decisions_csv(run_csv)
    # the estimator's time is the decision's only where it waited for that estimate (age 0)
    waited = decisions['estimator_age'] == 0
    latency = decisions['latency_ms'] + np.where(
        waited, np.nan_to_num(decisions['estimator_latency_ms']), 0.0)
    error = np.where(decisions['prediction_error'] < 0, np.nan, decisions['prediction_error'])
    surrogate = np.where(decisions['surrogate_valid'] > 0, decisions['surrogate'], np.nan)
    mode = decisions['mode'].astype(np.int64)
    if mode.size and (mode.min() < 0 or mode.max() >= len(MODES)):
        raise ValueError(f'{run_csv}: controller modes outside 0..{len(MODES) - 1}')
    return RunRecord(round_trip=rows['round_trip'].astype(np.int64), K=rows['K'], E=rows['E'],
                     M=rows['M'], O=rows['O'],
                     angles=np.stack([rows[f] for f in ('alpha1', 'alpha2', 'alpha3',
                                                        'alpha_p')], axis=1),
                     control_round_trip=decisions['round_trip'].astype(np.int64), mode=mode,
                     surrogate=surrogate, prediction_error=error,
                     iterations=decisions['iterations'].astype(np.int64), latency_ms=latency,
                     estimate=np.full(mode.shape, np.nan),  # run.controller.csv has none
                     meta=dict(meta or {}))


def run_graph(out_dir: Path, controller: str, scenario: str, settings: list[str],
              round_trips: int, period: int, initial_angles: np.ndarray,
              domain_id: int, lockstep: bool = True, models_dir: Path | None = None,
              meta: dict | None = None, record_bag: Path | None = None,
              plant: list[str] = (),
              measurement_round_trips: int = MEASUREMENT_ROUND_TRIPS,
              bench: list[str] = ()) -> RunRecord:
    """Run the bringup for one closed loop (recording a bag to ``record_bag`` if given;
    ``plant`` and ``bench``: the simulator's ``KEY=VALUE`` plant and bench settings);
    raises RuntimeError if it fails."""
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = out_dir / 'run.csv'
    cmd = [sys.executable, '-m', 'dlmpc_ros.bringup', '--controller', controller,
           '--scenario', scenario, '--round-trips', str(round_trips), '--period', str(period),
           '--initial-angles=' + ','.join(repr(float(a)) for a in initial_angles),
           '--csv', str(csv_path), '--log-dir', str(out_dir / 'logs'),
           '--domain-id', str(domain_id),
           '--measurement-round-trips', str(measurement_round_trips)]
    for item in settings:
        cmd += ['--scenario-param', item]
    for item in plant:
        cmd += ['--plant', item]
    for item in bench:
        cmd += ['--bench', item]
    if lockstep:
        cmd.append('--lockstep')
    if models_dir is not None:
        cmd += ['--models-dir', str(models_dir)]
    if record_bag is not None:
        cmd += ['--record', str(record_bag)]
    with open(out_dir / 'bringup.log', 'w') as log:
        code = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
    if code != 0:
        tail = (out_dir / 'bringup.log').read_text(errors='replace')[-2000:]
        raise RuntimeError(f'bringup exited with {code}; see {out_dir}/bringup.log:\n{tail}')
    return record_from_csv(csv_path, meta)
