"""The DL-MPC's modes: one object per way of choosing the next angles, with one verb.

Each period the supervisor (:class:`~dlmpc_ros.control.dlmpc.DLMPCController`) asks its
modes ``decide(period)`` in priority order; the first :class:`Decision` acts and the modes
after it ``stand_down`` (drop what they had under way). None passes. Highest first:

- :class:`AcquireMode` (``acquire``): lock scan (:mod:`~dlmpc_ros.control.acquisition`);
- :class:`TrackMode` (``track``): curve tracker (:mod:`~dlmpc_ros.control.tracking`);
- :class:`OuterLoop` (``outer``): MP-RNN plans (:mod:`~dlmpc_ros.control.planner`);
- :class:`InnerLoop` (``inner``): the estimator's surrogate through the K-to-angles map;
- :class:`HoldMode` (``hold``): keep the angles (no surrogate).

:class:`PredictionMonitor` keeps the MP-RNN's history and scores its one-step forecasts.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import torch

from dlmpc_ros.control.acquisition import LockSupervisor
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.planner import PlanProblem, solve_plan
from dlmpc_ros.control.tracking import CurveTracker
from dlmpc_ros.learning.mprnn import MPRNN

#: Recent periods whose one-step prediction errors are averaged.
ERROR_MEMORY = 3


@dataclass(frozen=True)
class Period:
    """What the supervisor knows in one control period."""

    current: np.ndarray
    """(4,) angles applied during the period [rad]."""
    objective: float
    """Measured O = E / M (NaN where M <= 0)."""
    surrogate: float
    """The estimator's K surrogate for the measurement (NaN: none)."""


@dataclass(frozen=True)
class Decision:
    """A mode's choice for the next period (the supervisor applies the servo limits)."""

    angles: np.ndarray
    """(4,) wanted angles [rad]."""
    mode: str
    """Name of the mode that decided."""
    surrogate: float | None = None
    """The estimate to report (None: the period's surrogate)."""
    predicted_objective: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """(N,) predicted O over the horizon (the outer loop's plans only)."""
    iterations: int = 0
    """Plan iterations (the outer loop's plans only)."""
    predicted_next: torch.Tensor | None = None
    """(2,) normalized state the plan predicts for the end of the next period."""
    travel: bool = False
    """The angles only move the servos on toward a goal (no measurement needed there)."""


class Mode(Protocol):
    """One way of choosing the angles."""

    name: str

    def decide(self, period: Period) -> Decision | None:
        """The angles for the next period, or None to pass to the next mode."""

    def stand_down(self) -> None:
        """A mode before this one acted: drop what was under way."""


class PredictionMonitor:
    """The MP-RNN's feature history and one-step accuracy: plan iterations grow by one after
    an accurate forecast (:meth:`expect`, scored by :meth:`observe`), shrink after a poor one."""

    def __init__(self, model: MPRNN, config: DLMPCConfig) -> None:
        self.model = model
        self.config = config
        self.history: deque[torch.Tensor] = deque(maxlen=model.min_history())
        self.errors: deque[float] = deque(maxlen=ERROR_MEMORY)
        self.iterations = config.start_iterations
        self._expected: torch.Tensor | None = None   # (2,) v forecast for this period

    def observe(self, x: torch.Tensor) -> float:
        """Add the period's features (10,); return their forecast's RMS error (NaN: none)."""
        self.history.append(x)
        if self._expected is None:
            return float('nan')
        error = float(torch.sqrt(((self._expected - x[:2]) ** 2).mean()))
        self.errors.append(error)
        cfg = self.config
        if error < cfg.accurate_error:
            self.iterations = min(cfg.max_iterations, self.iterations + 1)
        else:
            self.iterations = max(cfg.min_iterations, self.iterations - 1)
        return error

    def expect(self, v_next: torch.Tensor | None) -> None:
        """The forecast (2,) of the next period's normalized state (None: no forecast)."""
        self._expected = v_next

    @property
    def full(self) -> bool:
        """Whether the history is as long as a prediction needs."""
        return len(self.history) == self.history.maxlen

    @property
    def recent_error(self) -> float:
        """Mean of the recent forecast errors (0 before the first)."""
        return float(np.mean(self.errors)) if self.errors else 0.0

    def history_batch(self) -> torch.Tensor:
        """(1, N + 2b, 10) the history as the model's input."""
        return torch.stack(list(self.history))[None]


class AcquireMode:
    """Scan for a pulse while unlocked; the tracker (if any) enters where the scan locks."""

    name = 'acquire'

    def __init__(self, supervisor: LockSupervisor, tracker: CurveTracker | None = None) -> None:
        self.supervisor = supervisor
        self.tracker = tracker

    def decide(self, period: Period) -> Decision | None:
        scan = self.supervisor.step(period.objective, period.current, period.surrogate)
        if scan is not None:
            return Decision(scan, self.name, travel=self.supervisor.travelling)
        point = self.supervisor.locked_at
        if point is not None and point.branch and self.tracker is not None:
            self.tracker.enter_at(point.estimate, point.branch, period.objective)
        return None

    def stand_down(self) -> None:
        """Nothing to drop: the scan restarts from its own counters."""


class TrackMode:
    """Hold the laser on the tracking curve and follow K along it by the measured O."""

    name = 'track'

    def __init__(self, tracker: CurveTracker) -> None:
        self.tracker = tracker

    def decide(self, period: Period) -> Decision | None:
        on_curve = self.tracker.step(period.objective, period.current)
        if on_curve is None:
            return None
        return Decision(on_curve, 'plan' if self.tracker.planned else self.name,
                        surrogate=self.tracker.estimate)

    def stand_down(self) -> None:
        self.tracker.interrupt()


class OuterLoop:
    """MP-RNN planning (receding horizon); passes (dropping its plan) while the history is
    short or the recent error is over ``config.error_threshold`` (then it stays off)."""

    name = 'outer'

    def __init__(self, monitor: PredictionMonitor, config: DLMPCConfig) -> None:
        self.monitor = monitor
        self.config = config
        self.plan: torch.Tensor | None = None             # (N, 4) remaining plan

    def decide(self, period: Period) -> Decision | None:
        if not self.monitor.full or self.monitor.recent_error > self.config.error_threshold:
            self.stand_down()
            return None
        return self._solve(period)

    def stand_down(self) -> None:
        self.plan = None

    def _solve(self, period: Period) -> Decision:
        model = self.monitor.model
        history = self.monitor.history_batch()                      # (1, N + 2b, 10)
        if self.plan is None:
            with torch.no_grad():
                seed = model(history).u[0]                          # (N, 4) from the map
        else:
            seed = torch.cat([self.plan[1:], self.plan[-1:]])       # shift the old plan
        result = solve_plan(model, PlanProblem(
            history=history, seed=seed, current=period.current,
            iterations=self.monitor.iterations, learning_rate=self.config.learning_rate),
            self.config.limits)
        self.plan = result.plan
        return Decision(result.first, self.name, predicted_objective=result.predicted_objective,
                        iterations=result.iterations, predicted_next=result.predicted_next)


class InnerLoop:
    """The estimator's surrogate through the K-to-angles map (passes without one)."""

    name = 'inner'

    def __init__(self, map_angles: Callable[[float], np.ndarray]) -> None:
        self.map_angles = map_angles

    def decide(self, period: Period) -> Decision | None:
        if not np.isfinite(period.surrogate):
            return None
        return Decision(self.map_angles(period.surrogate), self.name)

    def stand_down(self) -> None:
        """Stateless."""


class HoldMode:
    """Keep the angles (the last resort: no surrogate)."""

    name = 'hold'

    def decide(self, period: Period) -> Decision:
        return Decision(period.current, self.name)

    def stand_down(self) -> None:
        """Stateless."""
