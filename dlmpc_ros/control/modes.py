"""The DL-MPC's modes: one object per way of choosing the next angles, with one verb.

Each period the supervisor (:class:`~dlmpc_ros.control.dlmpc.DLMPCController`, whose
docstring lists them in priority order) asks its modes ``decide(period)``; the first
:class:`Decision` acts and the modes after it ``stand_down`` (drop what they had under way).
None passes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from dlmpc_ros.control.acquisition import LockSupervisor
from dlmpc_ros.control.tracking import CurveTracker

if TYPE_CHECKING:  # the outer loop's forecast (control/planner.py)
    import torch


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
