"""A closed-loop run as arrays: what the laser did every round trip and what the
controller decided every control period. Written by the in-process loop, by a graph run
(the bringup's CSV files) and by a recorded bag, so that the metrics and figures read
one format."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from dlmpc_ros.control.step import MODES, ControlStep

ROUND_TRIP_FIELDS = ('round_trip', 'K', 'E', 'M', 'O', 'angles')
PERIOD_FIELDS = ('control_round_trip', 'mode', 'surrogate', 'prediction_error', 'iterations',
                 'latency_ms', 'estimate')


@dataclass
class RunRecord:
    """Arrays of one run. Per round trip (R,): ``round_trip``, ``K`` (the true K, for
    evaluation), ``E``, ``M``, ``O`` (NaN where the field blew up) and ``angles`` (R, 4)
    [rad] the round trip ran with. Per control period (C,): ``control_round_trip`` (the
    round trip whose measurement the controller acted on), ``mode`` (index into
    :data:`~dlmpc_ros.control.step.MODES`), ``surrogate``, ``prediction_error``,
    ``iterations``, ``latency_ms`` (estimate plus plan) and ``estimate`` (the estimator's
    own surrogate, whether the controller used it or not; NaN: no estimator, or a record
    made before it was kept)."""

    round_trip: np.ndarray
    K: np.ndarray
    E: np.ndarray
    M: np.ndarray
    O: np.ndarray  # noqa: E741 (the paper's name)
    angles: np.ndarray
    control_round_trip: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    mode: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    surrogate: np.ndarray = field(default_factory=lambda: np.zeros(0))
    prediction_error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    latency_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))
    estimate: np.ndarray = field(default_factory=lambda: np.zeros(0))
    meta: dict = field(default_factory=dict)

    @property
    def mode_names(self) -> list[str]:
        return [MODES[i] for i in self.mode]

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {f.name: getattr(self, f.name) for f in fields(self) if f.name != 'meta'}
        partial = path.with_name(path.name + '.partial')  # a kill never leaves half a file
        with open(partial, 'wb') as handle:
            np.savez_compressed(handle, meta=np.array(json.dumps(self.meta)), **arrays)
        os.replace(partial, path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> RunRecord:
        with np.load(path, allow_pickle=False) as data:
            arrays = {f.name: data[f.name] for f in fields(cls)
                      if f.name != 'meta' and f.name in data.files}
            meta = json.loads(str(data['meta']))
        if 'estimate' not in arrays:  # a record made before the estimate was kept
            arrays['estimate'] = np.full(arrays['control_round_trip'].shape, np.nan)
        return cls(**arrays, meta=meta)


class RecordBuilder:
    """Collects a run row by row (lists), then :meth:`build` makes the arrays."""

    def __init__(self, meta: dict | None = None) -> None:
        self.meta = dict(meta or {})
        self.rows: list[tuple] = []
        self.steps: list[tuple] = []

    def add_round_trip(self, round_trip: int, k: float, e: float, m: float, o: float,
                       angles: np.ndarray) -> None:
        self.rows.append((round_trip, k, e, m, o, *np.asarray(angles, float)))

    def add_step(self, round_trip: int, step: ControlStep, extra_latency_ms: float = 0.0,
                 estimate: float | None = None) -> None:
        """One control period; ``estimate`` is the estimator's surrogate (None: none)."""
        self.steps.append((round_trip, step.mode_index, step.surrogate, step.prediction_error,
                           step.iterations, step.latency_ms + extra_latency_ms,
                           np.nan if estimate is None else estimate))

    def build(self) -> RunRecord:
        rows = np.array(self.rows, float).reshape(-1, 9)
        steps = np.array(self.steps, float).reshape(-1, 7)
        return RunRecord(round_trip=rows[:, 0].astype(np.int64), K=rows[:, 1], E=rows[:, 2],
                         M=rows[:, 3], O=rows[:, 4], angles=rows[:, 5:9],
                         control_round_trip=steps[:, 0].astype(np.int64),
                         mode=steps[:, 1].astype(np.int64), surrogate=steps[:, 2],
                         prediction_error=steps[:, 3], iterations=steps[:, 4].astype(np.int64),
                         latency_ms=steps[:, 5], estimate=steps[:, 6], meta=self.meta)
