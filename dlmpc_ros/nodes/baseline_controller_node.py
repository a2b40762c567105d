"""baseline_controller: what a lab would use instead of DL-MPC, on the same topics, or
any controller of your own.

``controller`` selects ``esc`` (extremum seeking), ``ga`` (a genetic algorithm that
searches, then holds its best), ``passive`` (the angles best for the initial K, held),
``fixed_best`` (the angles with the best worst-case O over the K range) or ``oracle``
(evaluation only: subscribes ``/laser/sim_truth`` for the true K, which no other
controller reads), or any other registered name or ``package.module:factory``
(docs/controllers.md; without the estimator's surrogate). Publishes
``/controller/measurement``, ``/laser/angles_cmd`` and ``/controller/status`` once per
decision on ``/laser/state`` (at least a period apart, once the laser reports its last
command reached).
"""

from __future__ import annotations

import math
import sys

import numpy as np
from rclpy.experimental import EventsExecutor
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.factory import CONTROLLERS
from dlmpc_ros.control.ga import GAConfig
from dlmpc_ros.control.plugins import build
from dlmpc_ros.control.step import Controller
from dlmpc_ros.paths import models_dir
from dlmpc_ros.ros import params
from dlmpc_ros.ros.controller_base import ControllerNodeBase
from dlmpc_ros.ros.io import QOS

BASELINES = CONTROLLERS[1:]
_GA = GAConfig()
DEFAULTS: dict[str, object] = {'controller': 'fixed_best', 'angles': [0.0],
                               'initial_birefringence': math.nan,
                               'ga_population': _GA.population,
                               'ga_generations': _GA.generations, 'ga_dwell': _GA.dwell,
                               'ga_lock_objective': _GA.lock_objective,
                               'ga_restart_level': _GA.restart_level}
RANGES: dict[str, tuple[float, float]] = {
    'ga_population': (2, 10_000), 'ga_generations': (1, 100_000), 'ga_dwell': (1, 10_000),
    'ga_lock_objective': (1e-9, 1e4), 'ga_restart_level': (0.0, 1.0),
}
DESCRIPTIONS = {
    'controller': f'which controller: one of {BASELINES}, another registered name or '
                  'package.module:factory (docs/controllers.md)',
    'angles': 'passive only: the 4 angles to hold [rad] (else tuned for '
              'initial_birefringence)',
    'initial_birefringence': 'passive only: the K the passive setting was tuned for',
    'ga_population': 'ga: angle sets per generation',
    'ga_generations': 'ga: generations of one search',
    'ga_dwell': 'ga: control periods an individual is held after the servos arrive, before '
                'its O is its fitness',
    'ga_lock_objective': 'ga: O at which the best individual counts as mode-locked and is held',
    'ga_restart_level': 'ga: search again when O falls below this x the held O',
}


class BaselineControllerNode(ControllerNodeBase):
    def __init__(self) -> None:
        super().__init__('baseline_controller', DEFAULTS, DESCRIPTIONS, RANGES)
        angles = np.array(self.values['angles'], float)
        k0 = self.values['initial_birefringence']
        v = self.values
        try:
            ga = GAConfig(population=v['ga_population'], generations=v['ga_generations'],
                          dwell=v['ga_dwell'], lock_objective=v['ga_lock_objective'],
                          restart_level=v['ga_restart_level'])
            controller = build(
                self.values['controller'], models_dir(self.values['models_dir']), self.limits,
                angles=angles if angles.size == 4 else None,
                initial_k=None if math.isnan(k0) else k0, ga_config=ga)
        except (FileNotFoundError, ValueError) as err:  # ControllerSpecError: one line
            raise params.StartupError(str(err)) from None
        self._truth: dict[int, float] = {}
        if hasattr(controller, 'observe_truth'):  # the oracle (evaluation only)
            self.create_subscription(Float64MultiArray, itf.TOPIC_SIM_TRUTH, self._on_truth,
                                     QOS[itf.TOPIC_SIM_TRUTH])
        self.start(controller)

    def _on_truth(self, msg: Float64MultiArray) -> None:
        fault = itf.vector_fault(msg.data, itf.SIM_TRUTH_FIELDS, 1e300)
        if fault is not None:
            return self._warn.dropped(itf.TOPIC_SIM_TRUTH, fault)
        self._truth[int(msg.data[0])] = msg.data[1]  # a decision may come at any round trip
        while len(self._truth) > 1024:
            self._truth.pop(next(iter(self._truth)))
        return None

    def before_step(self, controller: Controller, state: np.ndarray) -> None:
        k = self._truth.get(int(state[0]))
        if k is not None:  # the simulator publishes the truth before the state
            controller.observe_truth(k)


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(BaselineControllerNode, args, executor_factory=EventsExecutor))


if __name__ == '__main__':
    main()
