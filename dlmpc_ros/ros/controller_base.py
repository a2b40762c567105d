"""What both controller nodes share: a decision at most once per control period of
/laser/state, on states taken at the angles it commanded.

Each state goes to the period's measurement (:class:`~dlmpc_ros.control.step.PeriodMeasurement`:
a decision is due ``period`` round trips after the last, once the servos have settled at the
last command for the round trips a measurement averages, or ``settle_timeout`` round trips
regardless). Its measurement is published on /controller/measurement (what the estimator
reads), the controller steps, and the node publishes the angles on /laser/angles_cmd and the
decision on /controller/status. A controller that reads the estimator's surrogate (the paper's
loops) acts once the estimate of the same round trip arrives, or ``estimator_timeout`` s
without it (:mod:`~dlmpc_ros.ros.estimates`); a decision is never skipped, since the
controller's histories assume one row per decision. /diagnostics carries the measured settle
time of the commands and warns when decisions had to be made before the servos settled.
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
from dlmpc_ros.ros.estimates import EstimateInbox, subscribe_when_heard
from dlmpc_ros.ros.io import QOS, vector_message

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
        self._inbox: EstimateInbox | None = None  # the surrogates, if the controller reads them
        self._last_acted = -1
        self.steps = 0
        self._last_state: float | None = None
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
        if self.uses_estimator:  # read the laser once the estimator reads the measurements
            self._inbox = EstimateInbox(self, self._try_act, self._warn)
            subscribe_when_heard(self, self._measurement_pub, self._subscribe_state)
            self.create_timer(0.02, self._check_timeout)
        else:
            self._subscribe_state()
        self._diagnostics = DiagnosticsPublisher(self, self._health)

    def _subscribe_state(self) -> None:
        self.create_subscription(Float64MultiArray, itf.TOPIC_STATE, self._on_state,
                                 QOS[itf.TOPIC_STATE])

    def _health(self, findings: Findings, now: float) -> Health:
        findings.new_drops(self._drops, self._warn)
        started = self._diagnostics.started
        findings.input(itf.TOPIC_STATE, self._last_state, started, now, silent_level=ERROR)
        if self._inbox is not None:  # the controller holds without it: a warning
            findings.input(itf.TOPIC_ESTIMATE, self._inbox.last_heard, started, now,
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

    def _check_timeout(self) -> None:
        now = self.get_clock().now().nanoseconds * 1e-9
        if (self._pending is not None
                and now - self._pending_since > self.values['estimator_timeout']):
            self._act(surrogate=None,
                      why=f"within {self.values['estimator_timeout']:g} s")

    def _try_act(self) -> None:
        if self._pending is None:
            return
        if self._inbox is None:
            self._act(None)
            return
        surrogate = self._inbox.surrogate(int(self._pending[0]))
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
        age = -1.0 if self._inbox is None else self._inbox.age(round_trip, self.period)
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
