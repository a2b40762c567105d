"""The measurement a controller and the estimator get for each decision, from the states
the laser reports every round trip, once the servos have reached the last command.

A decision falls at most once per P round trips, on states *settled* at its command (every
angle within ``tolerance``): the mean E and M of the settled states among the latest n round
trips, with their median angles (n: ``bench/results/measurement_round_trips.md``). It is due
once they have been settled for min(n, P) round trips (1 after ``measure=False``), or after
``timeout`` round trips regardless (:attr:`PeriodMeasurement.settled` says which). Without a
known command (before the first, after ``command(None)``) the latest state's angles count as
reached.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from dlmpc_ros.core import checks

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
    """Collects the round trips' states and says when a decision is due, with its measurement.

    ``period``: P [round trips], the least time between decisions; ``round_trips``: n >= 1
    averaged (an unreported one leaves a gap); ``tolerance`` >= 0 [rad]: of a settled state;
    ``timeout`` >= 1: round trips to a decision even if unsettled (never before P).
    """

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

    @property
    def last_decision(self) -> int:
        """Round trip of the latest decision (0 before the first)."""
        return self._last

    def wanted(self, round_trip: int) -> bool:
        """Whether round trip r's state can matter: for the next measurement, the servos'
        settle time, or as the start of a new run."""
        return (self._awaiting or (self._moved and self._first_settled is None)
                or round_trip > self._last + self.period - self.round_trips
                or round_trip < self._last)  # a new run

    def _at_command(self, state: np.ndarray, reference: np.ndarray) -> bool:
        return bool(np.abs(state[2:] - reference).max() <= self.tolerance)

    def command(self, angles: np.ndarray | None, measure: bool = True) -> None:
        """The command (4,) [rad] of the latest decision (None: unknown; the latest state's
        angles are the reference); no decision is due before it. ``measure=False``: the
        next comes once it is reached (>= P later), on however few settled states."""
        self._awaiting = False
        self._measure = bool(measure)
        self._command = None if angles is None else np.array(angles, float)
        latest = self._latest[-1][1][2:] if self._latest else None
        self._moved = (self._command is not None and latest is not None
                       and not self._at_command(self._latest[-1][1], self._command))
        since = [(r, self._settled(s)) for r, s in self._latest if r > self._last]
        self._first_settled = next((r for r, settled in since if settled), None)
        self._last_away = max((r for r, settled in since if not settled), default=self._last)

    def _settled(self, state: np.ndarray) -> bool:
        reference = self._command if self._command is not None else self._latest[-1][1][2:]
        return self._at_command(state, reference)

    def _settled_since(self) -> int | None:
        """Round trip since which the readings are at the reference (None: not at it): with a
        command, the one after the latest state away from it (unreported ones count as
        settled); without, the start of the trailing run at the latest state's angles."""
        if self._command is not None:
            return self._last_away + 1 if self._settled(self._latest[-1][1]) else None
        since = None
        for r, state in reversed(self._latest):
            if not self._settled(state):
                break
            since = r
        return since

    def add(self, round_trip: int, state: np.ndarray) -> np.ndarray | None:
        """Add round trip r's state (6,) ``(E, M, alpha[4])``; return the measurement (6,)
        when a decision is due, else None. An earlier round trip than the latest starts a
        new run (no command known); the latest one again replaces its state."""
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
