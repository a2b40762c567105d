"""The measurement a controller and the estimator get for each decision, from the states
the laser reports every round trip, once the servos have reached the last command.

A detector reads E and M every round trip; the controller decides at most once per
period of P round trips, and only on states taken at the angles it commanded: a state
counts once every reported angle is within ``tolerance`` of the command (it is
*settled*). The measurement ``(E, M, alpha[4])`` is the mean E and M of the settled
states among the latest ``round_trips`` (n) round trips, with their median reported
angles. A decision is due at the first round trip r >= (last decision) + P at which the
readings have been settled for min(n, P) round trips (since the round trip after the
latest state away from the command: a driver that skips round trip numbers is not held
up by the ones it did not report; 1 round trip after a command given with
``measure=False``: a controller that only moves the servos on needs no average), or at
(last decision) +
``timeout`` whatever they are (then, if the servos never settled, the measurement is the
latest state alone and :attr:`PeriodMeasurement.settled` says so). With servos that reach a
command on the next round trip every decision falls at a multiple of P, on the same
states as an unconditional period would use. Averaging n readings divides independent
detector noise by sqrt(n): the default n = 10 cut what 1 % noise on E and M cost on the
development plants (nominal cavity 0.012 -> 0.007, family plants 0.006 -> -0.003;
``bench/results/measurement_round_trips.md``).

Before the first command, and after ``command(None)`` (a reader that does not know the
commands, such as a bag's), the latest state's angles are taken as reached: a decision
falls every P round trips, on the trailing states at those angles.
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: Round trips a measurement averages by default (1: the decision's own only).
MEASUREMENT_ROUND_TRIPS = 10
#: Largest |reported angle - command| [rad] of a settled state by default: about 5x the
#: 0.05 degree (8.7e-4 rad) resolution of a typical motorized mount's encoder.
SETTLE_TOLERANCE = 0.005
#: Round trips after a decision by which the next one is made even if the command was not
#: reached (10 default periods).
SETTLE_TIMEOUT = 100


def period_measurement(states: np.ndarray) -> np.ndarray:
    """The measurement ``(E, M, alpha[4])`` of settled states (n, 6) ``(E, M,
    alpha[4])``: their mean E and M and their median angles (exact when they agree)."""
    states = np.asarray(states, float)
    if states.ndim != 2 or states.shape[1] != 6 or not len(states):
        raise ValueError(f'states must be (n >= 1, 6), got {states.shape}')
    return np.array([*states[:, :2].mean(axis=0), *np.median(states[:, 2:], axis=0)])


def _count(name: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
    return value


class PeriodMeasurement:
    """Collects the round trips' states and says when a decision is due, with its
    measurement.

    Parameters
    ----------
    period
        P [round trips]: the least time between two decisions.
    round_trips
        n: a measurement averages the settled states of the latest n round trips (>= 1);
        a round trip that reported nothing leaves a gap.
    tolerance
        Largest |reported angle - command| [rad] of a settled state (>= 0).
    timeout
        Round trips after a decision by which the next is made even if unsettled (>= 1;
        never before P).
    """

    def __init__(self, period: int, round_trips: int = MEASUREMENT_ROUND_TRIPS,
                 tolerance: float = SETTLE_TOLERANCE, timeout: int = SETTLE_TIMEOUT) -> None:
        self.period = _count('period', period)
        self.round_trips = _count('round_trips', round_trips)
        self.timeout = _count('timeout', timeout)
        if not (isinstance(tolerance, (int, float)) and 0 <= tolerance < np.inf):
            raise ValueError(f'tolerance must be a finite number >= 0, got {tolerance!r}')
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
        #: Round trips from the decision before the latest one to the first state at its
        #: command, when that command moved the servos and was reached; else None.
        self.settle_round_trips: int | None = None

    @property
    def last_decision(self) -> int:
        """Round trip of the latest decision (0 before the first)."""
        return self._last

    def wanted(self, round_trip: int) -> bool:
        """Whether round trip r's state can matter: it may enter the next measurement, the
        servos are on their way to the command (its settle time is measured), or it starts
        a new run."""
        return (self._awaiting or (self._moved and self._first_settled is None)
                or round_trip > self._last + self.period - self.round_trips
                or round_trip < self._last)  # a new run

    def _at_command(self, state: np.ndarray, reference: np.ndarray) -> bool:
        return bool(np.abs(state[2:] - reference).max() <= self.tolerance)

    def command(self, angles: np.ndarray | None, measure: bool = True) -> None:
        """The command (4,) [rad] decided on at the latest decision (None: not known;
        the latest state's angles are the reference). Call it after every decision; no
        decision is due before. ``measure=False``: the next decision comes once the
        command is reached (and at least P after this one), on the settled states there
        are by then, however few."""
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
        """Round trip since which the readings are at the reference: with a command, the
        one after the latest state away from it since the last decision (a state that was
        not reported counts as settled); without one, the start of the trailing run of
        states at the latest state's angles."""
        if self._command is not None:
            return self._last_away + 1 if self._settled(self._latest[-1][1]) else None
        since = None
        for r, state in reversed(self._latest):
            if not self._settled(state):
                break
            since = r
        return since

    def add(self, round_trip: int, state: np.ndarray) -> np.ndarray | None:
        """Add round trip r's state (6,) ``(E, M, alpha[4])``; when a decision is due,
        return its measurement (6,), else None. A round trip before the latest one starts
        a new run (a restarted laser: no command is known); the latest one again replaces
        its state."""
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
                                   if self._moved and self._first_settled is not None
                                   else None)
        self._last, self._awaiting = round_trip, True
        return period_measurement(np.array(window if self.settled else [state]))
