"""A controller node's control period, from the /laser/state callback to the published command.

Each usable state goes to the period's :class:`~dlmpc_ros.control.step.PeriodMeasurement`,
which says when a decision is due; the measurement goes out on /controller/measurement, the
controller steps, the angles go out on /laser/angles_cmd, the decision on /controller/status.
The paper's loops wait for the estimator's surrogate up to ``estimator_timeout`` s, never
skipping a decision. A non-finite command is never sent: the angles hold, the controller
starts afresh.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import AngleLimits, Controller, ControlStep, PeriodMeasurement
from dlmpc_ros.health import SettleWatch
from dlmpc_ros.ros.estimates import EstimateInbox
from dlmpc_ros.ros.io import vector_message

if TYPE_CHECKING:  # made by the node at start
    from dlmpc_ros.ros.controller_base import Publishers

#: Latest decisions whose modes /diagnostics sums up.
RECENT_DECISIONS = 1000


class DecisionLoop:
    """``controller`` decides within ``limits``, ``periods`` says when and on what,
    ``publishers`` send it; ``now()``: the node's clock [s]; ``inbox``: the estimator's
    surrogates (None: none read); ``before_step(controller, state)`` runs before each step
    (the oracle reads K there); ``fresh(controller)``: the controller after a non-finite one."""

    def __init__(self, controller: Controller, limits: AngleLimits, periods: PeriodMeasurement,
                 publishers: Publishers, warn: itf.RateLimitedLog, now: Callable[[], float],
                 inbox: EstimateInbox | None = None, estimator_timeout: float = 1.0,
                 before_step: Callable[[Controller, np.ndarray], None] | None = None,
                 fresh: Callable[[Controller], Controller] | None = None) -> None:
        self.controller, self.limits = controller, limits
        self.periods, self.publishers = periods, publishers
        self.inbox, self.estimator_timeout = inbox, estimator_timeout
        self._warn, self._now = warn, now
        self._before_step, self._fresh = before_step, fresh
        self._pending: np.ndarray | None = None  # the period's state message
        self._measurement = np.zeros(6)          # and its measurement
        self._pending_since = 0.0
        # what /diagnostics reports
        self.last_heard: float | None = None     # monotonic time of the latest state [s]
        self.last_acted, self.steps = -1, 0
        self.mode: str | None = None
        self.objective: float | None = None
        self.recent_modes: deque[str] = deque(maxlen=RECENT_DECISIONS)
        self.estimate_age: float | None = None
        self.settling = SettleWatch()

    def on_state(self, msg: Float64MultiArray) -> None:
        """The callback of /laser/state."""
        if not itf.usable_state(msg.data, self._warn):
            return
        self.last_heard = time.monotonic()
        round_trip = int(msg.data[0])
        if round_trip == self.last_acted or not self.periods.wanted(round_trip):
            return
        period = self.periods.period
        if self._pending is not None and round_trip >= int(self._pending[0]) + period:
            self._act(None, why="before the next period's state")  # the next may be due
        measurement = self.periods.add(round_trip, itf.measured_state(msg.data))
        if measurement is None:
            return
        if self._pending is not None:  # a new run (the laser restarted) before the answer
            self._act(None, why="before the next period's state")
        self._pending_since = self._now()
        self._pending, self._measurement = np.array(msg.data, float), measurement
        settled, settle = self.periods.settled, self.periods.settle_round_trips
        self.settling.add(settled, settle)
        self.publishers.measurement.publish(vector_message(itf.MEASUREMENT_FIELDS, [
            round_trip, *measurement, float(settled), -1.0 if settle is None else settle]))
        self.try_act()

    def try_act(self) -> None:
        """Act on the pending period if its surrogate is in, or none is awaited."""
        if self._pending is None:
            return
        if self.inbox is None:
            self._act(None)
            return
        surrogate = self.inbox.surrogate(int(self._pending[0]))
        if surrogate is not None:
            self._act(surrogate)

    def check_timeout(self) -> None:
        """Act without the surrogate once it is ``estimator_timeout`` s late."""
        if self._pending is not None \
                and self._now() - self._pending_since > self.estimator_timeout:
            self._act(None, why=f'within {self.estimator_timeout:g} s')

    def _act(self, surrogate: float | None, why: str = '') -> None:
        state, self._pending = self._pending, None
        round_trip = int(state[0])
        self.last_acted = round_trip
        measurement = self._measurement
        if self._before_step is not None:
            self._before_step(self.controller, state)
        step: ControlStep = self.controller.step(measurement, surrogate)
        if not np.isfinite(step.angles).all():  # never command a non-finite angle
            self._warn('nonfinite', f'controller produced {step.angles}; holding the angles '
                       'and starting the controller afresh')
            step = ControlStep(angles=self.limits.apply(measurement[2:6], measurement[2:6]),
                               mode='hold')
            if self._fresh is not None:
                self.controller = self._fresh(self.controller)
        self.periods.command(step.angles, step.measure)
        self.publishers.command.publish(vector_message(itf.ANGLE_FIELDS, step.angles))
        age = -1.0 if self.inbox is None else self.inbox.age(round_trip, self.periods.period)
        self.mode, self.objective = step.mode, float(state[3])
        self.recent_modes.append(step.mode)
        self.estimate_age = None if age < 0 else age
        valid = math.isfinite(step.surrogate)
        error = step.prediction_error if math.isfinite(step.prediction_error) else -1.0
        status = [round_trip, step.mode_index, error, step.iterations, step.latency_ms,
                  step.surrogate if valid else 0.0, float(valid), age]
        if surrogate is None and self.inbox is not None:
            self._warn('estimator', f'no estimate for round trip {round_trip} {why}: '
                       f'mode {step.mode}')
        self.publishers.status.publish(vector_message(
            [*itf.CONTROLLER_STATUS_FIELDS,
             *(f'predicted_O{i + 1}' for i in range(step.predicted_objective.size))],
            [*status, *np.nan_to_num(step.predicted_objective, nan=0.0, posinf=0.0,
                                     neginf=0.0)]))
        self.steps += 1
