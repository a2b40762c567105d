"""laser_sim: the simulated NPR mode-locked fiber laser as a ROS 2 node.

Publishes every round trip ``/laser/state``, ``/laser/objective`` and, for evaluation
only, ``/laser/sim_truth`` ``[round_trip, K]`` (the K that round trip ran with); subscribes
``/laser/angles_cmd`` ``[alpha1, alpha2, alpha3, alpha_p]`` (rad) and
``/laser/birefringence`` ``[K]``. Round trips run in a worker thread, free-running or
paced by ``round_trips_per_second``; commands take effect from the next round trip.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from dataclasses import fields

import numpy as np
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.core.cavity import INITIAL_CONDITIONS, Cavity
from dlmpc_ros.core.config import CavityConfig, config_problems
from dlmpc_ros.ros import params
from dlmpc_ros.ros.io import QOS, vector_message

CAVITY_NAMES = tuple(f.name for f in fields(CavityConfig))
DEFAULTS: dict[str, object] = {
    **CavityConfig().to_dict(),
    'initial_angles': [-0.39, -0.25, 0.52, -0.14], 'initial_birefringence': 0.1,
    'initial': 'sech', 'seed': 0, 'round_trips_per_second': 0.0, 'max_round_trips': 0,
    'angle_limit': 2 * math.pi, 'birefringence_limit': 1.0, 'wait_for_subscribers': 0,
}
DESCRIPTIONS = {
    'initial_angles': 'alpha1, alpha2, alpha3, alpha_p at start [rad]',
    'initial_birefringence': 'K at start, until /laser/birefringence says otherwise',
    'initial': f'initial field, one of {INITIAL_CONDITIONS}',
    'seed': 'seed of the noise initial condition',
    'round_trips_per_second': 'pace of the simulation; 0 runs as fast as possible',
    'max_round_trips': 'stop after this many round trips; 0 runs until shut down',
    'angle_limit': 'angle commands with any |alpha| above this [rad] are rejected',
    'birefringence_limit': 'K messages with |K| above this are rejected',
    'wait_for_subscribers': 'hold the first round trip until /laser/state has this many '
                            'subscribers (so that recorders miss nothing)',
}
READ_ONLY = frozenset({'points', 'window', 'initial', 'seed', 'initial_angles',
                       'initial_birefringence', 'wait_for_subscribers'})


class LaserSimNode(Node):
    def __init__(self) -> None:
        super().__init__('laser_sim')
        self.values = params.declare(self, DEFAULTS, DESCRIPTIONS, READ_ONLY)
        problems = self._problems(self.values)
        if problems:
            raise params.StartupError('; '.join(problems))
        self.cavity = Cavity(self._cavity_config(self.values), batch=1,
                             angles=np.array(self.values['initial_angles']),
                             birefringence=self.values['initial_birefringence'],
                             initial=self.values['initial'], seed=self.values['seed'])
        self.finished = False
        self.exit_code = 0
        self._lock = threading.Lock()
        self._pending: dict[str, object] = {}
        self._warn = itf.RateLimitedLog(self.get_logger().warning)
        self._state_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_STATE,
                                                QOS[itf.TOPIC_STATE])
        self._objective_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_OBJECTIVE,
                                                    QOS[itf.TOPIC_OBJECTIVE])
        self._truth_pub = self.create_publisher(Float64MultiArray, itf.TOPIC_SIM_TRUTH,
                                                QOS[itf.TOPIC_SIM_TRUTH])
        for topic, handler in ((itf.TOPIC_ANGLES_CMD, self._on_angles),
                               (itf.TOPIC_BIREFRINGENCE, self._on_birefringence)):
            self.create_subscription(Float64MultiArray, topic, handler, QOS[topic])
        self.add_on_set_parameters_callback(lambda ps: params.result(
            self._problems({**self.values, **{p.name: p.value for p in ps}})))
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._stop = threading.Event()
        self._worker = threading.Thread(target=self._run, name='round_trips', daemon=True)
        self._worker.start()

    @staticmethod
    def _cavity_config(values: dict) -> CavityConfig:
        return CavityConfig(**{name: values[name] for name in CAVITY_NAMES})

    @staticmethod
    def _problems(values: dict) -> list[str]:
        problems = config_problems({name: values[name] for name in CAVITY_NAMES})
        angles = values['initial_angles']
        if len(angles) != 4 or not all(math.isfinite(a) for a in angles):
            problems.append(f'initial_angles must be 4 finite numbers, got {list(angles)}')
        if values['initial'] not in INITIAL_CONDITIONS:
            problems.append(f'initial must be one of {INITIAL_CONDITIONS}, '
                            f"got {values['initial']!r}")
        for name in ('round_trips_per_second', 'max_round_trips', 'angle_limit',
                     'birefringence_limit', 'initial_birefringence', 'wait_for_subscribers'):
            value = values[name]
            if not math.isfinite(value) or (name != 'initial_birefringence' and value < 0):
                problems.append(f'{name} must be finite and >= 0, got {value}')
        return problems

    def _apply_parameters(self, changed) -> None:
        with self._lock:
            self.values.update({p.name: p.value for p in changed})
            self._pending['config'] = self._cavity_config(self.values)

    def _on_vector(self, topic: str, msg: Float64MultiArray, limit: float):
        fault = itf.vector_fault(msg.data, itf.FIELDS[topic], limit)
        if fault is not None:
            self._warn(f'{topic}:{fault.split()[0]}', f'dropped a message on {topic}: {fault}')
            return None
        return np.array(msg.data, dtype=float)

    def _on_angles(self, msg: Float64MultiArray) -> None:
        angles = self._on_vector(itf.TOPIC_ANGLES_CMD, msg, self.values['angle_limit'])
        if angles is not None:
            with self._lock:
                self._pending['angles'] = angles

    def _on_birefringence(self, msg: Float64MultiArray) -> None:
        k = self._on_vector(itf.TOPIC_BIREFRINGENCE, msg, self.values['birefringence_limit'])
        if k is not None:
            with self._lock:
                self._pending['birefringence'] = k[0]

    def _apply_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, {}
        if 'config' in pending:
            self.cavity.config = pending['config']
        if 'angles' in pending:
            self.cavity.set_angles(pending['angles'])
        if 'birefringence' in pending:
            self.cavity.set_birefringence(pending['birefringence'])

    def _run(self) -> None:
        """Worker thread: round trips until stopped or max_round_trips is reached."""
        try:
            self._round_trips()
        except Exception as err:  # never die silently while the node keeps spinning
            if not (self._stop.is_set() or not self.context.ok()):
                self.get_logger().fatal(f'simulation stopped: {type(err).__name__}: {err}')
                self.exit_code = 1
        finally:
            self.finished = True

    def _round_trips(self) -> None:
        wanted = self.values['wait_for_subscribers']
        while self._state_pub.get_subscription_count() < wanted and not self._stop.wait(0.01):
            pass
        next_time = time.monotonic()
        limit = self.values['max_round_trips']
        while not self._stop.is_set() and (limit == 0 or self.cavity.round_trip < limit):
            self._apply_pending()
            k = float(self.cavity.birefringence[0])
            result = self.cavity.step()
            if not result.finite[0]:
                self.get_logger().error(f'field blew up at round trip {self.cavity.round_trip};'
                                        ' reset to the initial pulse')
                self.cavity.reset()
                continue
            row = result.laser(0)
            state = [row['round_trip'], row['E'], row['M'], row['O'], row['energy'],
                     row['peak'], *self.cavity.angles[0]]
            self._truth_pub.publish(vector_message(itf.SIM_TRUTH_FIELDS, [row['round_trip'], k]))
            self._state_pub.publish(vector_message(itf.STATE_FIELDS, state))
            self._objective_pub.publish(vector_message(itf.OBJECTIVE_FIELDS, [row['O']]))
            rate = self.values['round_trips_per_second']
            if rate > 0:
                next_time = max(next_time + 1.0 / rate, time.monotonic() - 1.0)
                self._stop.wait(max(0.0, next_time - time.monotonic()))

    def stop(self) -> None:
        """Stop the worker thread and wait for it (call before destroying the node)."""
        self._stop.set()
        self._worker.join()


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(LaserSimNode, args))


if __name__ == '__main__':
    main()
