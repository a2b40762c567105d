"""drift_injector: publishes the true birefringence K on /laser/birefringence.

K advances with the laser's own clock: for every ``/laser/state`` message of round trip
r (every ``publish_every``-th), it publishes ``[K(r + 1)]`` for the next round trip. The
scenario (``scenario`` parameter) and its settings (the shared names of
:mod:`dlmpc_ros.core.drift`) are fixed at start. True K is for the simulator and for
evaluation only: no controller subscribes to it.
"""

from __future__ import annotations

import sys
import time

from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.core.drift import PARAMETER_NAMES, SCENARIOS, make_scenario
from dlmpc_ros.health import WARN, CounterWindow, Findings, Health
from dlmpc_ros.ros import params
from dlmpc_ros.ros.diagnostics import DiagnosticsPublisher
from dlmpc_ros.ros.io import QOS, vector_message

DEFAULTS: dict[str, object] = {'scenario': 'sinusoidal', 'publish_every': 1,
                               **{name: None for name in PARAMETER_NAMES}}
DESCRIPTIONS = {
    'scenario': f'drift scenario, one of {SCENARIOS}',
    'publish_every': 'publish K on every n-th laser round trip',
    'offset': 'K offset (mean of sinusoidal/chirp/random_walk, level of constant/steps)',
    'amplitude': 'K amplitude of sinusoidal and chirp',
    'period': 'period of sinusoidal, length of the chirp sweep [round trips]',
    'phase': 'phase of sinusoidal and chirp [rad]',
    'sigma': 'stationary standard deviation of random_walk',
    'correlation_time': 'correlation time of random_walk [round trips]',
    'seed': 'seed of random_walk',
    'times': 'round trips at which steps switches to the next value',
    'values': 'K values of steps',
    'path': 'CSV (round_trip, K) for replay',
}
READ_ONLY = frozenset(DEFAULTS)
RANGES = {'publish_every': (1, 10 ** 6)}
#: A state may run at most this many round trips past the furthest one seen: the drift is
#: made round trip by round trip (a random walk's path up to r costs time in r), so a
#: round trip far ahead (a corrupt counter) is dropped instead of stalling the node.
MAX_AHEAD = 10 ** 6


class DriftInjectorNode(Node):
    def __init__(self) -> None:
        super().__init__('drift_injector')
        values = params.declare(self, DEFAULTS, DESCRIPTIONS, READ_ONLY, RANGES)
        settings = {name: values[name] for name in PARAMETER_NAMES
                    if self.get_parameter(name).type_ != Parameter.Type.NOT_SET}
        try:
            self.scenario = make_scenario(str(values['scenario']), **settings)
        except (ValueError, TypeError) as err:
            raise params.StartupError(str(err)) from None
        self.publish_every = int(values['publish_every'])
        if self.publish_every < 1:
            raise params.StartupError(f'publish_every must be >= 1, got {self.publish_every}')
        self._warn = itf.RateLimitedLog(self.get_logger().warning)
        self._furthest = 0
        self.published = 0
        self.states_received = 0
        self._scenario_name = str(values['scenario'])
        self._last_state: float | None = None
        self._drops = CounterWindow()
        self._diagnostics = DiagnosticsPublisher(self, self._health)
        self._pub = self.create_publisher(Float64MultiArray, itf.TOPIC_BIREFRINGENCE,
                                          QOS[itf.TOPIC_BIREFRINGENCE])
        self.create_subscription(Float64MultiArray, itf.TOPIC_STATE, self._on_state,
                                 QOS[itf.TOPIC_STATE])
        self.get_logger().info(f'drift scenario {values["scenario"]} {settings}')

    def _on_state(self, msg: Float64MultiArray) -> None:
        self.states_received += 1
        if not itf.usable_state(msg.data, self._warn):
            return
        round_trip = int(msg.data[0])
        self._last_state = time.monotonic()
        if round_trip > self._furthest + MAX_AHEAD:
            self._warn.dropped(itf.TOPIC_STATE, f'round_trip {round_trip} runs more than '
                               f'{MAX_AHEAD} past the furthest seen ({self._furthest})')
            return
        self._furthest = max(self._furthest, round_trip)
        if round_trip % self.publish_every == 0:
            k = float(self.scenario(round_trip + 1))
            self._pub.publish(vector_message(itf.BIREFRINGENCE_FIELDS, [k]))
            self.published += 1

    def _health(self, findings: Findings, now: float) -> Health:
        findings.values.update(scenario=self._scenario_name, k_published=self.published,
                               furthest_round_trip=self._furthest)
        findings.new_drops(self._drops, self._warn)
        findings.input(itf.TOPIC_STATE, self._last_state, self._diagnostics.started, now,
                       silent_level=WARN)
        return findings.health(f'{self.published} K published, scenario '
                               f'{self._scenario_name}')

    def drain(self, executor) -> None:
        """Take the states still queued when asked to stop and publish their K: at full
        speed the injector can be some hundred round trips behind the laser, and each
        round trip the laser ran should have its K in a recording (the recorder stops
        last)."""
        params.drain_until_quiet(executor, lambda: self.states_received, longest=5.0)

    def stop(self) -> None:
        """Log what was published (the other side's count is in laser_sim's log)."""
        self.get_logger().info(f'published {self.published} K messages, last for round '
                               f'trip {self._furthest + 1}')


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(DriftInjectorNode, args, executor_factory=EventsExecutor))


if __name__ == '__main__':
    main()
