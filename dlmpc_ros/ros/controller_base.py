"""What both controller nodes share: their parameters, the decision loop a control period
runs through (:class:`~dlmpc_ros.ros.decision_loop.DecisionLoop`: /laser/state in, the
command out), the estimator's surrogates where the controller reads them
(:mod:`~dlmpc_ros.ros.estimates`) and /diagnostics, which carries the measured settle time of
the commands and warns when decisions had to be made before the servos settled.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from rclpy.node import Node
from rclpy.publisher import Publisher
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import Controller
from dlmpc_ros.health import ERROR, WARN, CounterWindow, Findings, Health, controller_health
from dlmpc_ros.ros import params
from dlmpc_ros.ros.controller_params import (COMMON_DEFAULTS, COMMON_DESCRIPTIONS,
                                             COMMON_RANGES, limits_from,
                                             period_measurement_from)
from dlmpc_ros.ros.decision_loop import DecisionLoop
from dlmpc_ros.ros.diagnostics import DiagnosticsPublisher
from dlmpc_ros.ros.estimates import EstimateInbox, subscribe_when_heard
from dlmpc_ros.ros.io import QOS


class Publishers(NamedTuple):
    """Where a decision goes: /laser/angles_cmd, /controller/status, /controller/measurement."""

    command: Publisher
    status: Publisher
    measurement: Publisher


class ControllerNodeBase(Node):
    """Subclasses build their controller and call :meth:`start` with it at the end of
    __init__; from then on the decision loop holds it (:attr:`loop`)."""

    uses_estimator = False  # set by start(): whether the controller reads the surrogate

    def __init__(self, name: str, defaults: dict, descriptions: dict,
                 ranges: dict[str, tuple[float, float]] | None = None) -> None:
        super().__init__(name)
        self.values = params.declare(self, {**COMMON_DEFAULTS, **defaults},
                                     {**COMMON_DESCRIPTIONS, **descriptions},
                                     frozenset(COMMON_DEFAULTS) | frozenset(defaults),
                                     {**COMMON_RANGES, **(ranges or {})})
        self.limits = limits_from(self.values)
        self._periods = period_measurement_from(self.values)
        self.loop: DecisionLoop | None = None
        self._warn = itf.RateLimitedLog(self.get_logger().warning)
        self._drops = CounterWindow()

    def start(self, controller: Controller) -> None:
        # a controller that reads the VAE's surrogate (the paper's loops) waits for it
        self.uses_estimator = bool(getattr(controller, 'uses_estimator', False))
        publishers = Publishers(*(
            self.create_publisher(Float64MultiArray, topic, QOS[topic])
            for topic in (itf.TOPIC_ANGLES_CMD, itf.TOPIC_CONTROLLER_STATUS,
                          itf.TOPIC_MEASUREMENT)))
        self.loop = DecisionLoop(
            controller, self.limits, self._periods, publishers, self._warn,
            now=lambda: self.get_clock().now().nanoseconds * 1e-9,
            inbox=EstimateInbox(self._warn) if self.uses_estimator else None,
            estimator_timeout=self.values['estimator_timeout'],
            before_step=self.before_step, fresh=self.fresh_controller)
        if self.uses_estimator:  # read the laser once the estimator reads the measurements
            self.create_subscription(Float64MultiArray, itf.TOPIC_ESTIMATE, self._on_estimate,
                                     QOS[itf.TOPIC_ESTIMATE])
            subscribe_when_heard(self, publishers.measurement, self._subscribe_state)
            self.create_timer(0.02, self.loop.check_timeout)
        else:
            self._subscribe_state()
        self._diagnostics = DiagnosticsPublisher(self, self._health)

    def _subscribe_state(self) -> None:
        self.create_subscription(Float64MultiArray, itf.TOPIC_STATE, self.loop.on_state,
                                 QOS[itf.TOPIC_STATE])

    def _on_estimate(self, msg: Float64MultiArray) -> None:
        if self.loop.inbox.add(msg):
            self.loop.try_act()

    def _health(self, findings: Findings, now: float) -> Health:
        loop = self.loop
        findings.new_drops(self._drops, self._warn)
        started = self._diagnostics.started
        findings.input(itf.TOPIC_STATE, loop.last_heard, started, now, silent_level=ERROR)
        if loop.inbox is not None:  # the controller holds without it: a warning
            findings.input(itf.TOPIC_ESTIMATE, loop.inbox.last_heard, started, now,
                           silent_level=WARN)
        loop.settling.report(findings, self.values['settle_timeout'],
                             self.values['settle_tolerance'])
        supervisor = getattr(loop.controller, 'acquisition', None)
        return controller_health(findings, loop.mode, loop.objective,
                                 getattr(supervisor, 'threshold', None), loop.steps,
                                 loop.estimate_age, self.uses_estimator, loop.recent_modes)

    def before_step(self, controller: Controller, state: np.ndarray) -> None:
        """Hook run just before the controller's step (the oracle reads its K here)."""

    def fresh_controller(self, controller: Controller) -> Controller:
        """A controller without memory of past periods, to replace one whose output went
        non-finite (a measurement it could not digest may sit in its history); by default
        the same one."""
        return controller

    def stop(self) -> None:
        """Log what was published (laser_sim's log holds the commands it received)."""
        steps = 0 if self.loop is None else self.loop.steps
        last = -1 if self.loop is None else self.loop.last_acted
        self.get_logger().info(f'published {steps} commands and {steps} status '
                               f'messages, last for round trip {last}')
