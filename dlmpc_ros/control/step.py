"""One control period as every controller sees it: its measurement (:class:`PeriodMeasurement`),
the servo limits (:class:`AngleLimits`), the step it returns (:class:`ControlStep`,
:class:`Controller`); and what the DL-MPC's modes take and return (:class:`Period`,
:class:`Decision`, :class:`Mode`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from dlmpc_ros.core import checks

if TYPE_CHECKING:
    import torch


#: Modes a controller reports (``plan``: tracking periods with a planned turn; ``custom``: a
#: plug-in's own, docs/controllers.md). The index is published: a new mode goes at the end.
MODES = ('inner', 'outer', 'hold', 'passive', 'fixed_best', 'esc', 'oracle', 'acquire',
         'track', 'ga', 'plan', 'custom', 'bo', 'drl')


@dataclass(frozen=True)
class ControlStep:
    """A period's decision: ``angles`` (4,) [rad] from the next round trip on, and diagnostics."""

    angles: np.ndarray
    mode: str
    surrogate: float = float('nan')
    prediction_error: float = float('nan')  # NaN until a prediction could be checked
    predicted_objective: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,)
    iterations: int = 0
    latency_ms: float = 0.0
    measure: bool = True  # False: the angles only move the servos on (decide once reached)

    @property
    def mode_index(self) -> int:
        return MODES.index(self.mode)


#: Bounds of a laser's E = sqrt(energy) and spectral kurtosis M; a state outside them is a
#: glitch, on which a learning controller holds and keeps it out of its history.
E_RANGE = (0.0, 1e4)
M_RANGE = (1.0, 1e5)
#: Largest |angle| a servo may report [rad].
ANGLE_BOUND = 1e3


def implausible(measurement: np.ndarray) -> bool:
    """Whether a measurement ``(E, M, alpha1..alpha_p)`` is no laser's: a value not finite, E
    or M outside its range, or an angle beyond ``ANGLE_BOUND``."""
    e, m = float(measurement[0]), float(measurement[1])
    return bool(not np.isfinite(measurement).all() or not E_RANGE[0] <= e <= E_RANGE[1]
                or not M_RANGE[0] <= m <= M_RANGE[1]
                or np.abs(measurement[2:6]).max() > ANGLE_BOUND)


class Controller(Protocol):
    """Measurement ``(E, M, alpha[4])`` and the estimator's K surrogate (None: none, or not
    ``uses_estimator``) in, next angles out; only the oracle gets K (``observe_truth``)."""

    name: str

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        ...


@dataclass(frozen=True)
class Period:
    """What the supervisor knows in one control period."""

    current: np.ndarray  # (4,) angles applied during the period [rad]
    objective: float     # measured O = E / M (NaN where M <= 0)
    surrogate: float     # the estimator's K surrogate for the measurement (NaN: none)
    energy: float        # measured E


@dataclass(frozen=True)
class Decision:
    """A mode's choice for the next period (the supervisor applies the servo limits)."""

    angles: np.ndarray            # (4,) wanted angles [rad]
    mode: str                     # name of the mode that decided
    surrogate: float | None = None  # the estimate to report (None: the period's surrogate)
    #: (N,) predicted O over the horizon, the plan's iterations, and the (2,) normalized
    #: state it predicts for the end of the next period (the outer loop's plans only)
    predicted_objective: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iterations: int = 0
    predicted_next: torch.Tensor | None = None
    travel: bool = False  # the angles only move the servos on (no measurement needed there)


class Mode:
    """One way of choosing the angles."""

    name = ''

    def decide(self, period: Period) -> Decision | None:
        """The angles for the next period, or None to pass to the next mode."""
        raise NotImplementedError

    def stand_down(self) -> None:
        """A mode before this one acted: drop what was under way (by default, nothing)."""


@dataclass(frozen=True)
class AngleLimits:
    """Servo range and speed: a wanted angle (pi-periodic) becomes its equivalent in ``[low,
    high]`` nearest the current one, reached by at most ``max_step`` per period."""

    low: float = -2 * math.pi
    """Lowest angle a servo may be sent to [rad] (two turns: room for branch turns)."""
    high: float = 2 * math.pi
    """Highest angle a servo may be sent to [rad]."""
    max_step: float = 0.25
    """Largest change of any angle per control period [rad] (servo speed)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ValueError(f'angle limits must be finite with low < high, got '
                             f'[{self.low}, {self.high}]')
        if not self.max_step > 0:
            raise ValueError(f'max_step must be > 0 rad, got {self.max_step}')

    def apply(self, current: np.ndarray, wanted: np.ndarray) -> np.ndarray:
        """The angles (4,) [rad] to command, from the current (4,) and the wanted (4,) ones."""
        current = np.clip(np.asarray(current, float), self.low, self.high)
        wanted = np.asarray(wanted, float)
        goal = wanted + math.pi * np.round((current - wanted) / math.pi)  # nearest of all
        goal = into_range(goal, self.low, self.high)
        reachable = (goal >= self.low) & (goal <= self.high)   # a range narrower than pi
        goal = np.where(reachable, goal, np.clip(wanted, self.low, self.high))
        return current + np.clip(goal - current, -self.max_step, self.max_step)


def into_range(goal: np.ndarray, low: float, high: float) -> np.ndarray:
    """Angles (any shape) [rad] beyond a limit moved by whole multiples of pi to the nearest
    equivalent in ``[low, high]`` (still outside if the range is under pi), others unchanged."""
    goal = np.where(goal > high, goal - math.pi * np.ceil((goal - high) / math.pi), goal)
    return np.where(goal < low, goal + math.pi * np.ceil((low - goal) / math.pi), goal)


#: Round trips a measurement averages by default (1: the decision's own only).
MEASUREMENT_ROUND_TRIPS = 10
#: Default largest |reported angle - command| [rad] of a settled state (5x a 0.05 deg encoder).
SETTLE_TOLERANCE = 0.005
#: Round trips after a decision by which the next is made even if unsettled (10 default periods).
SETTLE_TIMEOUT = 100


def period_measurement(states: np.ndarray) -> np.ndarray:
    """Mean E, M and median angles (6,) of settled states (n, 6) ``(E, M, alpha[4])``."""
    states = np.asarray(states, float)
    if states.ndim != 2 or states.shape[1] != 6 or not len(states):
        raise ValueError(f'states must be (n >= 1, 6), got {states.shape}')
    return np.array([*states[:, :2].mean(axis=0), *np.median(states[:, 2:], axis=0)])


class PeriodMeasurement:
    """Collects the round trips' states and says when a decision is due, with its measurement:
    at most once per ``period`` P round trips, the mean E and M (median angles) of the states
    *settled* at the command (every angle within ``tolerance`` [rad]) among the latest
    ``round_trips`` n, once they have been settled for min(n, P) round trips (1 after
    ``measure=False``), or after ``timeout`` round trips regardless (:attr:`settled` says
    which). Without a known command the latest state's angles count as reached."""

    def __init__(self, period: int, round_trips: int = MEASUREMENT_ROUND_TRIPS,
                 tolerance: float = SETTLE_TOLERANCE, timeout: int = SETTLE_TIMEOUT) -> None:
        self.period, self.round_trips, self.timeout = period, round_trips, timeout
        self.tolerance = tolerance
        checks.counts(self, 'period', 'round_trips', 'timeout')
        checks.non_negative(self, 'tolerance')
        self.tolerance = float(tolerance)
        self._latest: deque[tuple[int, np.ndarray]] = deque(maxlen=round_trips)
        self._last = 0                        # round trip of the last decision
        self._command: np.ndarray | None = None
        self._awaiting = False                # decided, its command not given yet
        self._moved = False                   # the command moved the servos
        self._first_settled: int | None = None
        self._last_away = 0                   # latest state away from the command
        self._measure = True                  # the next decision needs a measurement
        #: Whether the latest measurement was of settled states.
        self.settled = True
        #: Round trips from the previous decision to the first state at its command, if
        #: that command moved the servos and was reached; else None.
        self.settle_round_trips: int | None = None

    def wanted(self, round_trip: int) -> bool:
        """Whether round trip r's state can matter (the measurement, settle time, a new run)."""
        return (self._awaiting or (self._moved and self._first_settled is None)
                or round_trip > self._last + self.period - self.round_trips
                or round_trip < self._last)  # a new run

    def _at_command(self, state: np.ndarray, reference: np.ndarray) -> bool:
        return bool(np.abs(state[2:] - reference).max() <= self.tolerance)

    def command(self, angles: np.ndarray | None, measure: bool = True) -> None:
        """The latest decision's command (4,) [rad] (None: unknown); none is due till then.
        ``measure=False``: the next comes once it is reached, on however few states."""
        self._awaiting, self._measure = False, bool(measure)
        self._command = None if angles is None else np.array(angles, float)
        self._moved = (self._command is not None and bool(self._latest)
                       and not self._at_command(self._latest[-1][1], self._command))
        since = [(r, self._settled(s)) for r, s in self._latest if r > self._last]
        self._first_settled = next((r for r, settled in since if settled), None)
        self._last_away = max((r for r, settled in since if not settled), default=self._last)

    def _settled(self, state: np.ndarray) -> bool:
        reference = self._command if self._command is not None else self._latest[-1][1][2:]
        return self._at_command(state, reference)

    def _settled_since(self) -> int | None:
        """Round trip since which the states are at the command (None: not at it), or without
        one, at the latest state's angles (unreported round trips count as settled)."""
        if self._command is not None:
            return self._last_away + 1 if self._settled(self._latest[-1][1]) else None
        since = None
        for r, state in reversed(self._latest):
            if not self._settled(state):
                break
            since = r
        return since

    def add(self, round_trip: int, state: np.ndarray) -> np.ndarray | None:
        """Round trip r's state (6,) ``(E, M, alpha[4])`` -> the measurement (6,) when a
        decision is due, else None (an earlier round trip than the latest: a new run)."""
        if self._latest and round_trip == self._latest[-1][0]:
            self._latest.pop()  # the same round trip again: its latest state counts
        elif self._latest and round_trip < self._latest[-1][0]:
            self._latest.clear()  # the round trips start again (a new run)
            self._last, self._command, self._awaiting = 0, None, False
            self._moved, self._first_settled, self._last_away = False, None, 0
        state = np.asarray(state, float)
        self._latest.append((round_trip, state))
        if self._awaiting:
            return None
        if self._command is not None:
            if not self._settled(state):
                self._last_away = round_trip
            elif self._first_settled is None:
                self._first_settled = round_trip
        elapsed = round_trip - self._last
        if elapsed < self.period:
            return None
        since = self._settled_since()
        needed = (min(self.round_trips, self.period)
                  if self._command is not None and self._measure else 1)
        settled_long_enough = since is not None and round_trip - since + 1 >= needed
        if not settled_long_enough and elapsed < max(self.timeout, self.period):
            return None
        window = [s for r, s in self._latest
                  if r > round_trip - self.round_trips and self._settled(s)]
        self.settled = bool(window) and since is not None
        self.settle_round_trips = (self._first_settled - self._last
                                   if self._moved and self._first_settled is not None else None)
        self._last, self._awaiting = round_trip, True
        return period_measurement(np.array(window if self.settled else [state]))
