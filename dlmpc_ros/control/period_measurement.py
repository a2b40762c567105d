"""The measurement a controller and the estimator get once per control period, from the
states the laser reports every round trip.

A detector reads E and M every round trip; the controller decides once per period of P
round trips. Its measurement ``(E, M, alpha[4])`` is the mean E and M over the period's
last ``round_trips`` round trips that ran at the angles of the period's own round trip
(an angle change starts a new run of states: what the laser did under other angles does
not count), with those angles. Averaging n readings divides independent detector noise
by sqrt(n); with ``round_trips = 1`` the measurement is the period's own round trip's, as
the paper's controller reads it. The default, the whole default period of 10, cut what 1 %
noise on E and M cost on the development plants (nominal cavity 0.012 -> 0.007, family
plants 0.006 -> -0.003) and cost nothing without noise
(``bench/results/measurement_round_trips.md``).
"""

from __future__ import annotations

from collections import deque

import numpy as np

#: Round trips a period's measurement averages by default (1: the period's own only).
MEASUREMENT_ROUND_TRIPS = 10


def period_measurement(states: np.ndarray) -> np.ndarray:
    """The measurement ``(E, M, alpha[4])`` from the latest states (n, 6) ``(E, M,
    alpha[4])``, oldest first: the mean E and M of the trailing states that ran at the
    last state's angles, with those angles."""
    states = np.asarray(states, float)
    if states.ndim != 2 or states.shape[1] != 6 or not len(states):
        raise ValueError(f'states must be (n >= 1, 6), got {states.shape}')
    same = np.all(states[:, 2:] == states[-1, 2:], axis=1)
    start = 0 if same.all() else len(states) - int(np.argmin(same[::-1]))
    return np.array([*states[start:, :2].mean(axis=0), *states[-1, 2:]])


class PeriodMeasurement:
    """Collects the round trips' states and gives each control period's measurement.

    Parameters
    ----------
    period
        Control period P [round trips]: a measurement for every round trip r with
        r % P == 0.
    round_trips
        How many of the latest round trips (r - n, r] a measurement may average (>= 1);
        a round trip that reported nothing (a lost message, a reset laser) leaves a gap.
    """

    def __init__(self, period: int, round_trips: int = MEASUREMENT_ROUND_TRIPS) -> None:
        for name, value in (('period', period), ('round_trips', round_trips)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f'{name} must be an integer >= 1, got {value!r}')
        self.period = period
        self.round_trips = round_trips
        self._latest: deque[tuple[int, np.ndarray]] = deque(maxlen=round_trips)

    def wanted(self, round_trip: int) -> bool:
        """Whether round trip r's state can enter a measurement (one of the n round trips
        before a period's round trip, or that round trip itself)."""
        return (-round_trip) % self.period < self.round_trips

    def add(self, round_trip: int, state: np.ndarray) -> np.ndarray | None:
        """Add round trip r's state (6,) ``(E, M, alpha[4])``; at a period's round trip
        return its measurement (6,), else None. A round trip before the latest one starts
        a new run; the latest one again replaces its state."""
        if self._latest and round_trip == self._latest[-1][0]:
            self._latest.pop()  # the same round trip again: its latest state counts
        elif self._latest and round_trip < self._latest[-1][0]:
            self._latest.clear()  # the round trips start again (a new run)
        self._latest.append((round_trip, np.asarray(state, float)))
        if round_trip % self.period:
            return None
        states = [s for r, s in self._latest if r > round_trip - self.round_trips]
        return period_measurement(np.array(states))
