"""Topic names, message field layouts and input checks shared by every node (no rclpy).

A hardware driver replacing ``laser_sim`` publishes and subscribes the same topics with
the same layouts. All messages are ``std_msgs/Float64MultiArray``; the field names of a
topic are its layout's single dimension label, joined by commas.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence

TOPIC_STATE = '/laser/state'
TOPIC_OBJECTIVE = '/laser/objective'
TOPIC_ANGLES_CMD = '/laser/angles_cmd'
TOPIC_BIREFRINGENCE = '/laser/birefringence'
#: Simulator only: the K each round trip was simulated with, for evaluation and recording.
#: A hardware driver does not publish it, and no controller may subscribe to it.
TOPIC_SIM_TRUTH = '/laser/sim_truth'
TOPIC_LASER_STATUS = '/laser/status'
#: The estimator's K surrogate (not K in K's units) and its latent mean, once per period.
TOPIC_ESTIMATE = '/estimator/birefringence'
#: What the controller decided in each control period.
TOPIC_CONTROLLER_STATUS = '/controller/status'
#: The measurement each decision is made on (the estimator reads it).
TOPIC_MEASUREMENT = '/controller/measurement'
#: Every node's health once a second (diagnostic_msgs/DiagnosticArray; keys in
#: docs/interfaces.md, levels in :mod:`dlmpc_ros.health`).
TOPIC_DIAGNOSTICS = '/diagnostics'

#: Fields of /laser/state, one message per round trip (angles in radians).
STATE_FIELDS = ('round_trip', 'E', 'M', 'O', 'energy', 'peak',
                'alpha1', 'alpha2', 'alpha3', 'alpha_p')
OBJECTIVE_FIELDS = ('O',)
ANGLE_FIELDS = ('alpha1', 'alpha2', 'alpha3', 'alpha_p')
#: Columns of /laser/state that make the state a controller measures: E, M, the angles.
MEASURED_COLUMNS = tuple(STATE_FIELDS.index(f) for f in ('E', 'M', *ANGLE_FIELDS))
BIREFRINGENCE_FIELDS = ('K',)
SIM_TRUTH_FIELDS = ('round_trip', 'K')
#: Laser status, once a second: measured rate [round trips/s] and counters since start.
LASER_STATUS_FIELDS = ('round_trip', 'rate', 'commands_received', 'birefringence_received',
                       'messages_rejected', 'resets', 'lockstep_timeouts')
#: /estimator/birefringence: round trip of the measurement, surrogate, the estimator's
#: own latency [ms], then the latent mean (as many values as the VAE has latents).
ESTIMATE_FIELDS = ('round_trip', 'surrogate', 'latency_ms')
#: /controller/status, one per control period: mode is an index into
#: dlmpc_ros.control.step.MODES; prediction_error is -1 until a prediction was checked;
#: surrogate is the one used (in mode 'track' the curve tracker's K estimate, in K's
#: units; 0 with surrogate_valid = 0 when there was none);
#: estimator_age is the number of periods since the last estimate (-1: none yet);
#: latency [ms] is the controller's own step; then the predicted O over the horizon
#: (outer loop only). Every value is finite.
CONTROLLER_STATUS_FIELDS = ('round_trip', 'mode', 'prediction_error', 'iterations',
                            'latency_ms', 'surrogate', 'surrogate_valid', 'estimator_age')

#: /controller/measurement, one per decision: the decision's round trip, the mean E and M
#: of its settled states and their angles; settled is 1, or 0 when the decision came at
#: the settle timeout before the servos reached the command (then E, M and the angles are
#: the latest state's); settle_round_trips is the round trips from the previous decision
#: to the first state at its command, -1 when it did not move the servos or was not
#: reached.
MEASUREMENT_FIELDS = ('round_trip', 'E', 'M', *ANGLE_FIELDS, 'settled', 'settle_round_trips')

FIELDS = {
    TOPIC_STATE: STATE_FIELDS,
    TOPIC_OBJECTIVE: OBJECTIVE_FIELDS,
    TOPIC_ANGLES_CMD: ANGLE_FIELDS,
    TOPIC_BIREFRINGENCE: BIREFRINGENCE_FIELDS,
    TOPIC_SIM_TRUTH: SIM_TRUTH_FIELDS,
    TOPIC_LASER_STATUS: LASER_STATUS_FIELDS,
    TOPIC_MEASUREMENT: MEASUREMENT_FIELDS,
}


def vector_fault(data: Sequence[float], fields: Sequence[str], limit: float) -> str | None:
    """Describe what is wrong with a received vector, or None if it is usable.

    Parameters
    ----------
    data
        The message's ``data``.
    fields
        Expected field names; the length must match.
    limit
        Largest allowed absolute value of any element.
    """
    if len(data) != len(fields):
        return f'expected {len(fields)} values ({", ".join(fields)}), got {len(data)}'
    for name, value in zip(fields, data):
        if not math.isfinite(value):
            return f'{name} is {value}'
        if abs(value) > limit:
            return f'{name} = {value:g} is outside [-{limit:g}, {limit:g}]'
    return None


def measured_state(data: Sequence[float]) -> list[float]:
    """``(E, M, alpha[4])`` of a /laser/state vector: the state a period's measurement
    averages (:class:`~dlmpc_ros.control.step.PeriodMeasurement`)."""
    return [float(data[i]) for i in MEASURED_COLUMNS]


#: Largest round trip a float64 holds exactly (2**53); anything above is not a count.
MAX_ROUND_TRIP = 2 ** 53


def counted_fault(data: Sequence[float], fields: Sequence[str]) -> str | None:
    """What is wrong with a vector of ``fields`` whose first is a round trip (lengths,
    non-finite values, a round trip that is not a count in 0..MAX_ROUND_TRIP), or None."""
    fault = vector_fault(data, fields, 1e300)
    if fault is None and not (0 <= data[0] <= MAX_ROUND_TRIP and data[0] == int(data[0])):
        fault = f'round_trip = {data[0]} is not a count'
    return fault


def state_fault(data: Sequence[float]) -> str | None:
    """What is wrong with a /laser/state vector (:func:`counted_fault`), or None."""
    return counted_fault(data, STATE_FIELDS)


def usable_state(data: Sequence[float], warn: RateLimitedLog) -> bool:
    """Whether a /laser/state vector can be used; a malformed one is reported through
    ``warn`` (rate-limited, with what is wrong) and is to be dropped."""
    fault = state_fault(data)
    if fault is not None:
        warn.dropped(TOPIC_STATE, fault)
    return fault is None


class RateLimitedLog:
    """Log each distinct key (the nodes use the topic of a dropped message) at most once per
    ``period`` seconds, with a count of the messages suppressed in between.

    Parameters
    ----------
    log
        Function taking the text, e.g. a ROS logger's ``warning``.
    period
        Seconds between two lines of the same key.
    clock
        Monotonic time source in seconds.
    """

    def __init__(self, log: Callable[[str], object], period: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._period = period
        self._clock = clock
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        #: Messages dropped per topic, and the last reason (for /diagnostics).
        self.dropped_counts: dict[str, int] = {}
        self.last_fault: dict[str, str] = {}

    def __call__(self, key: str, text: str) -> bool:
        """Log ``text`` unless ``key`` was logged within the period; True if it was logged."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._period:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return False
        count = self._suppressed.pop(key, 0)
        suffix = f' ({count} similar messages suppressed)' if count else ''
        self._log(text + suffix)
        self._last[key] = now
        return True

    def dropped(self, topic: str, fault: str) -> bool:
        """Report a message dropped on ``topic`` for ``fault`` (rate-limited per topic)."""
        self.dropped_counts[topic] = self.dropped_counts.get(topic, 0) + 1
        self.last_fault[topic] = fault
        return self(topic, f'dropped a message on {topic}: {fault}')
