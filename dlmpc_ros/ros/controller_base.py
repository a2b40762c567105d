"""What both controller nodes share: a decision at most once per control period of
/laser/state, on states taken at the angles it commanded.

A decision is due at least ``period`` round trips after the last one, once the reported
angles have been within ``settle_tolerance`` of the last command for the round trips a
measurement averages, or ``settle_timeout`` round trips after the last decision whatever
they are (:class:`~dlmpc_ros.control.step.PeriodMeasurement`): its
measurement, the mean E and M of the last ``measurement_round_trips`` settled states with
their angles, is published on /controller/measurement (what the estimator reads). A node
that uses the estimator acts once the estimate of the same round trip arrives, or after
``estimator_timeout`` seconds without it (the controller then gets no surrogate and says
so on its status, ``estimator_age`` = periods since the last estimate). A decision is
never skipped: when a period has passed since the pending decision and its estimate has
not come, the pending one is acted on at once without it, because the controller's
histories assume one row per decision. It publishes the angles on /laser/angles_cmd and
the decision on /controller/status; /diagnostics carries the measured settle time of its
commands and warns when decisions had to be made before the servos settled.
"""

from __future__ import annotations

import math
import time
from collections import deque

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import Controller, ControlStep
from dlmpc_ros.health import (ERROR, WARN, CounterWindow, Findings, Health, SettleWatch,
                              controller_health)
from dlmpc_ros.ros import params
from dlmpc_ros.ros.controller_params import (COMMON_DEFAULTS, COMMON_DESCRIPTIONS,
                                             COMMON_RANGES, limits_from,
                                             period_measurement_from)
from dlmpc_ros.ros.diagnostics import DiagnosticsPublisher
from dlmpc_ros.ros.io import QOS, vector_message

#: Longest wait at start for the estimator to read /controller/measurement [s].
ESTIMATOR_WAIT = 3.0
#: Latest decisions whose modes /diagnostics sums up.
RECENT_DECISIONS = 1000


class ControllerNodeBase(Node):
    """Subclasses set ``self.controller`` and call :meth:`start` at the end of __init__."""

    uses_estimator = False  # set by start(): whether the controller reads the surrogate

    def __init__(self, name: str, defaults: dict, descriptions: dict,
                 ranges: dict[str, tuple[float, float]] | None = None) -> None:
        super().__init__(name)
        self.values = params.declare(self, {**COMMON_DEFAULTS, **defaults},
                                     {**COMMON_DESCRIPTIONS, **descriptions},
                                     frozenset(COMMON_DEFAULTS) | frozenset(defaults),
                                     {**COMMON_RANGES, **(ranges or {})})
        self.limits = limits_from(self.values)
        self.period = int(self.values['period'])
        self._periods = period_measurement_from(self.values)
        self.controller: Controller | None = None
        self._warn = itf.RateLimitedLog(self.get_logger().warning)
        self._pending: np.ndarray | None = None        # the period's state message
        self._pending_measurement = np.zeros(6)        # and its measurement
        self._pending_since = 0.0
        self._estimates: dict[int, float] = {}
        self._last_estimate_round_trip: int | None = None
        self._last_acted = -1
        self.steps = 0
        self._last_state: float | None = None
        self._last_estimate: float | None = None
        self._last_mode: str | None = None
        self._recent_modes: deque[str] = deque(maxlen=RECENT_DECISIONS)
        self._last_objective: float | None = None
        self._estimate_age: float | None = None
        self._drops = CounterWindow()
        self._settling = SettleWatch()

    def start(self) -> None:
        # a controller that reads the VAE's surrogate (the paper's loops) waits for it
        self.uses_estimator = bool(getattr(self.controller, 'uses_estimator', False))
        self._cmd_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_ANGLES_CMD,
                                              QOS[itf.TOPIC_ANGLES_CMD])
        self._status_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_CONTROLLER_STATUS,
                                                 QOS[itf.TOPIC_CONTROLLER_STATUS])
        self._measurement_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_MEASUREMENT,
                                                      QOS[itf.TOPIC_MEASUREMENT])
        if self.uses_estimator:
            self.create_subscription(Float64MultiArray, itf.TOPIC_ESTIMATE, self._on_estimate,
                                     QOS[itf.TOPIC_ESTIMATE])
            # read the laser once the estimator reads the measurements (or after a wait),
            # so that the first decision does not wait for an estimate that cannot come
            waiting_since = time.monotonic()

            def subscribe_when_heard() -> None:
                heard = self._measurement_pub.get_subscription_count() > 0
                if heard or time.monotonic() - waiting_since > ESTIMATOR_WAIT:
                    if not heard:
                        self.get_logger().warning(
                            f'no estimator reads {itf.TOPIC_MEASUREMENT} after '
                            f'{ESTIMATOR_WAIT:g} s; controlling without it until it does')
                    self._subscription_timer.cancel()
                    self._subscribe_state()
            self._subscription_timer = self.create_timer(0.02, subscribe_when_heard)
        else:
            self._subscribe_state()
        self.create_timer(0.02, self._check_timeout)
        self._diagnostics = DiagnosticsPublisher(self, self._health)

    def _subscribe_state(self) -> None:
        self.create_subscription(Float64MultiArray, itf.TOPIC_STATE, self._on_state,
                                 QOS[itf.TOPIC_STATE])

    def _health(self, findings: Findings, now: float) -> Health:
        findings.new_drops(self._drops, self._warn)
        started = self._diagnostics.started
        findings.input(itf.TOPIC_STATE, self._last_state, started, now, silent_level=ERROR)
        if self.uses_estimator:  # the controller holds without it: a warning
            findings.input(itf.TOPIC_ESTIMATE, self._last_estimate, started, now,
                           silent_level=WARN)
        self._settling.report(findings, self.values['settle_timeout'],
                              self.values['settle_tolerance'])
        supervisor = getattr(self.controller, 'acquisition', None)
        return controller_health(findings, self._last_mode, self._last_objective,
                                 getattr(supervisor, 'threshold', None), self.steps,
                                 self._estimate_age, self.uses_estimator, self._recent_modes)

    def _on_state(self, msg: Float64MultiArray) -> None:
        if not itf.usable_state(msg.data, self._warn):
            return None
        self._last_state = time.monotonic()
        round_trip = int(msg.data[0])
        if round_trip == self._last_acted or not self._periods.wanted(round_trip):
            return None
        if self._pending is not None and round_trip >= int(self._pending[0]) + self.period:
            self._act(None, why="before the next period's state")  # the next may be due
        measurement = self._periods.add(round_trip, itf.measured_state(msg.data))
        if measurement is None:
            return None
        if self._pending is not None:  # a new run (the laser restarted) before the answer
            self._act(None, why="before the next period's state")
        self._pending_since = self.get_clock().now().nanoseconds * 1e-9
        self._pending = np.array(msg.data, float)
        self._pending_measurement = measurement
        settled, settle = self._periods.settled, self._periods.settle_round_trips
        self._settling.add(settled, settle)
        self._measurement_pub.publish(vector_message(itf.MEASUREMENT_FIELDS, [
            round_trip, *measurement, float(settled), -1.0 if settle is None else settle]))
        self._try_act()
        return None

    def _on_estimate(self, msg: Float64MultiArray) -> None:
        data = msg.data
        fault = None
        if len(data) < len(itf.ESTIMATE_FIELDS):
            fault = f'expected at least {len(itf.ESTIMATE_FIELDS)} values, got {len(data)}'
        elif not all(math.isfinite(x) and abs(x) < 1e300 for x in data):
            fault = 'non-finite or out-of-range value'
        elif data[0] < 0 or data[0] != int(data[0]):
            fault = f'round_trip = {data[0]} is not a count'
        if fault is not None:
            return self._warn.dropped(itf.TOPIC_ESTIMATE, fault)
        round_trip = int(data[0])
        self._last_estimate = time.monotonic()
        self._estimates[round_trip] = float(data[1])
        self._last_estimate_round_trip = round_trip
        while len(self._estimates) > 64:
            self._estimates.pop(next(iter(self._estimates)))
        self._try_act()
        return None

    def _check_timeout(self) -> None:
        now = self.get_clock().now().nanoseconds * 1e-9
        if (self._pending is not None
                and now - self._pending_since > self.values['estimator_timeout']):
            self._act(surrogate=None,
                      why=f"within {self.values['estimator_timeout']:g} s")

    def _try_act(self) -> None:
        if self._pending is None:
            return
        if not self.uses_estimator:
            self._act(None)
            return
        surrogate = self._estimates.get(int(self._pending[0]))
        if surrogate is not None:
            self._act(surrogate)

    def before_step(self, state: np.ndarray) -> None:
        """Hook run just before the controller's step (the oracle reads its K here)."""

    def fresh_controller(self) -> Controller:
        """A controller without memory of past periods, to replace one whose output went
        non-finite (a measurement it could not digest may sit in its history); by default
        the same one."""
        return self.controller

    def _act(self, surrogate: float | None, why: str = '') -> None:
        state, self._pending = self._pending, None
        round_trip = int(state[0])
        self._last_acted = round_trip
        measurement = self._pending_measurement
        self.before_step(state)
        step: ControlStep = self.controller.step(measurement, surrogate)
        if not np.isfinite(step.angles).all():  # never command a non-finite angle
            self._warn('nonfinite', f'controller produced {step.angles}; holding the angles '
                       'and starting the controller afresh')
            step = ControlStep(angles=self.limits.apply(measurement[2:6], measurement[2:6]),
                               mode='hold')
            self.controller = self.fresh_controller()
        self._periods.command(step.angles, step.measure)
        self._cmd_pub.publish(vector_message(itf.ANGLE_FIELDS, step.angles))
        age = -1.0 if self._last_estimate_round_trip is None else (
            (round_trip - self._last_estimate_round_trip) / self.period)
        self._last_mode, self._last_objective = step.mode, float(state[3])
        self._recent_modes.append(step.mode)
        self._estimate_age = None if age < 0 else age
        valid = math.isfinite(step.surrogate)
        error = step.prediction_error if math.isfinite(step.prediction_error) else -1.0
        status = [round_trip, step.mode_index, error, step.iterations, step.latency_ms,
                  step.surrogate if valid else 0.0, float(valid), age]
        if surrogate is None and self.uses_estimator:
            self._warn('estimator', f'no estimate for round trip {round_trip} {why}: '
                       f'mode {step.mode}')
        self._status_pub.publish(vector_message(
            [*itf.CONTROLLER_STATUS_FIELDS,
             *(f'predicted_O{i + 1}' for i in range(step.predicted_objective.size))],
            [*status, *np.nan_to_num(step.predicted_objective, nan=0.0, posinf=0.0,
                                     neginf=0.0)]))
        self.steps += 1

    def stop(self) -> None:
        """Log what was published (laser_sim's log holds the commands it received)."""
        self.get_logger().info(f'published {self.steps} commands and {self.steps} status '
                               f'messages, last for round trip {self._last_acted}')
