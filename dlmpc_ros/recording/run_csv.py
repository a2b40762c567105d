"""The bringup's CSV files (no rclpy): the run (one row per round trip: the state fields
and the true K) and the control decisions (one row per control period). Written by the
bringup's monitor and by ``dlmpc-bag csv``, read by the evaluation and the plots."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dlmpc_ros import interfaces as itf

RUN_FIELDS = (*itf.STATE_FIELDS, 'K')
DECISION_FIELDS = (*itf.CONTROLLER_STATUS_FIELDS, 'estimator_latency_ms')


def write_header(writer) -> None:
    """Run CSV header: the state fields and the true K."""
    writer.writerow(RUN_FIELDS)


def write_row(writer, values: Sequence[float]) -> None:
    """One CSV row of floats, written exactly (``repr``)."""
    writer.writerow([repr(float(x)) for x in values])


def decisions_path(csv_path: Path) -> Path:
    """Where the control decisions of a run CSV go: ``run.csv`` -> ``run.controller.csv``."""
    return Path(csv_path).with_suffix('.controller.csv')


def _columns(path: Path) -> dict[str, np.ndarray]:
    with open(path) as handle:
        names = handle.readline().strip().split(',')
    data = np.loadtxt(path, delimiter=',', skiprows=1, ndmin=2)
    data = data.reshape(-1, len(names))
    return {name: data[:, i] for i, name in enumerate(names)}


def read_run_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of a bringup run CSV (``round_trip, E, M, O, ..., K``) as arrays."""
    return _columns(Path(path))


def read_decisions_csv(run_csv: Path) -> dict[str, np.ndarray]:
    """Columns of the decisions CSV that belongs to ``run_csv``."""
    return _columns(decisions_path(run_csv))
