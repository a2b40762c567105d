"""What a bringup run's picture and summary show (``bringup --plot``, ``make demo``): the
run beside the uncontrolled laser, i.e. the same cavity from the same angles with those
angles held, on the same K(t), and the envelope O*(K(t)), in the paper's layout
(:func:`~dlmpc_ros.evaluation.figures.plot_tracking`), plus one summary line."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.control.baselines import PassiveController
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.evaluation.closed_loop import run_closed_loop
from dlmpc_ros.evaluation.figures import plot_tracking
from dlmpc_ros.evaluation.graph_run import record_from_csv
from dlmpc_ros.evaluation.metrics import run_metrics
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.evaluation.report import summary_line

UNCONTROLLED = 'uncontrolled (start angles held)'


class RecordedDrift:
    """K(r) of a recorded run (held before its first and after its last round trip)."""

    def __init__(self, record: RunRecord) -> None:
        self.round_trip = record.round_trip.astype(float)
        self.k = record.K

    def __call__(self, round_trip):
        return np.interp(round_trip, self.round_trip, self.k)


def uncontrolled(record: RunRecord, cavity: CavityConfig, period: int) -> RunRecord:
    """The same laser from the run's first angles, held, on the run's K(t)."""
    start = record.angles[0]
    return run_closed_loop(PassiveController(start), RecordedDrift(record),
                           int(record.round_trip[-1]), period, start, cavity_config=cavity)


def demo_report(run_csv: Path, png: Path, controller: str, cavity: CavityConfig,
                period: int, envelope: dict | None) -> str:
    """Write the figure of a bringup run to ``png``; returns the summary line (ratio to
    the envelope, locked fraction, acquisition; measured figures only without one)."""
    record = record_from_csv(run_csv)
    if record.round_trip.size < 2 * period:
        raise ValueError(f'{run_csv}: too few round trips to plot ({record.round_trip.size})')
    records = {controller: record, UNCONTROLLED: uncontrolled(record, cavity, period)}
    plot_tracking(records, envelope, controller, f'{controller}: {Path(run_csv).name}', png)
    if envelope is None:
        return (f'{controller}: mean O {np.nanmean(record.O):.4f} against '
                f'{np.nanmean(records[UNCONTROLLED].O):.4f} uncontrolled (no envelope for '
                'this plant)')
    mine = run_metrics(record, envelope)
    theirs = run_metrics(records[UNCONTROLLED], envelope)
    return (f'{controller}: {summary_line(mine)}; uncontrolled: oracle ratio '
            f"{theirs['oracle_ratio']:.3f}")
