"""Closed-loop metrics of a run against the oracle envelope O*(K) (numpy only).

Definitions (round trips counted from the first one of the run):

- ``mean_O``: mean objective over all round trips (a blown-up round trip counts as 0);
  ``mean_oracle_O``: mean of O*(K(t)) over the same round trips;
  ``oracle_ratio`` = mean_O / mean_oracle_O.
- locked: a round trip with O >= ``lock_fraction`` x O*(K(t)) (half, by default).
- ``acquisition_round_trips``: round trips before the first run of ``hold`` consecutive
  locked round trips begins (None if the laser never locks that long).
- ``locked_fraction``: share of locked round trips from acquisition on.
- recovery after a step in K (a jump of more than ``step_threshold`` between two round
  trips): round trips from the jump to the next run of ``hold`` locked round trips.
- control-step latency (estimate plus plan): median and 99th percentile [ms].

Round trips without a true K (a recorded bag whose last truths never came) are left out
of the K metrics; a run with no K at all (a real laser) gets only the measured ones.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from dlmpc_ros.control.step import MODES
from dlmpc_ros.core import checks
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.learning.tables import envelope_objective


@dataclass(frozen=True)
class MetricSettings:
    """What counts as locked, acquired and recovered (see the module docstring)."""

    lock_fraction: float = 0.5
    """A round trip is locked when O >= this x O*(K(t))."""
    hold: int = 200
    """Consecutive locked round trips that make an acquisition or a recovery."""
    step_threshold: float = 0.02
    """A change of K between two round trips above this is a step."""

    def __post_init__(self) -> None:
        checks.fraction(self, 'lock_fraction')
        checks.counts(self, 'hold')
        checks.positive(self, 'step_threshold')


def first_hold(locked: np.ndarray, start: int, hold: int) -> int | None:
    """Index of the first run of ``hold`` consecutive True at or after ``start``."""
    run = 0
    for i in range(start, locked.size):
        run = run + 1 if locked[i] else 0
        if run >= hold:
            return i - hold + 1
    return None


def run_metrics(record: RunRecord, envelope: dict[str, np.ndarray],
                settings: MetricSettings | None = None) -> dict:
    """All metrics of one run as a JSON-ready dict."""
    s = settings or MetricSettings()
    known = np.isfinite(record.K)
    if not known.all():  # a hardware laser (no true K), or the last truths never came
        if not known.any():
            return _measured_only(record)
        record = _rows(record, known)
    o = np.nan_to_num(record.O, nan=0.0)
    o_star = envelope_objective(envelope, record.K)
    locked = o >= s.lock_fraction * o_star
    hold = min(s.hold, max(1, o.size // 4))
    acquired = first_hold(locked, 0, hold)
    jumps = np.flatnonzero(np.abs(np.diff(record.K)) > s.step_threshold) + 1
    recoveries = []
    for j in jumps:
        back = first_hold(locked, int(j), hold)
        recoveries.append(None if back is None else int(back - j))
    done = [r for r in recoveries if r is not None]
    after = slice(acquired if acquired is not None else o.size, None)
    return {
        'round_trips': int(o.size),
        'round_trips_without_K': int((~known).sum()),
        'mean_O': float(o.mean()),
        'mean_oracle_O': float(o_star.mean()),
        'oracle_ratio': float(o.mean() / o_star.mean()),
        'oracle_ratio_after_acquisition': (float(o[after].mean() / o_star[after].mean())
                                           if acquired is not None else None),
        'locked_fraction': float(locked[after].mean()) if acquired is not None else 0.0,
        'acquisition_round_trips': None if acquired is None else int(acquired),
        'blown_up_round_trips': int(np.isnan(record.O).sum()),
        'steps_in_K': int(jumps.size),
        'recovery_round_trips': recoveries,
        'recovery_round_trips_max': max(done) if done else None,
        **_control_metrics(record),
        'settings': asdict(s),
    }


def _control_metrics(record: RunRecord) -> dict:
    latency = record.latency_ms
    return {
        'step_latency_ms_median': float(np.median(latency)) if latency.size else None,
        'step_latency_ms_p99': float(np.percentile(latency, 99)) if latency.size else None,
        'control_periods': int(latency.size),
        'mode_fractions': {name: float(np.mean(record.mode == i))
                           for i, name in enumerate(MODES) if np.any(record.mode == i)},
    }


def _measured_only(record: RunRecord) -> dict:
    """The metrics that need no true K (a run on a real laser); the others are None."""
    o = np.nan_to_num(record.O, nan=0.0)
    return {
        'round_trips': int(o.size),
        'round_trips_without_K': int(o.size),
        'mean_O': float(o.mean()) if o.size else None,
        **{key: None for key in ('mean_oracle_O', 'oracle_ratio',
                                 'oracle_ratio_after_acquisition', 'locked_fraction',
                                 'acquisition_round_trips', 'recovery_round_trips_max')},
        'blown_up_round_trips': int(np.isnan(record.O).sum()),
        **_control_metrics(record),
    }


def _rows(record: RunRecord, keep: np.ndarray) -> RunRecord:
    """The record restricted to the round trips ``keep`` (control periods unchanged)."""
    return replace(record, round_trip=record.round_trip[keep], K=record.K[keep],
                   E=record.E[keep], M=record.M[keep], O=record.O[keep],
                   angles=record.angles[keep])
