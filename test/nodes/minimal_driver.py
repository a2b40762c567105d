"""A laser driver written from docs/interfaces.md alone: rclpy and std_msgs, no dlmpc_ros.

``python test/nodes/minimal_driver.py ROUND_TRIPS_PER_SECOND`` publishes /laser/state and
/laser/objective every round trip and applies /laser/angles_cmd through servos that
start 3 round trips after a command and turn 0.1 rad per round trip, with an encoder of
0.05 degree steps and 1 % detector noise. Its "laser" is a stand-in: E falls off with
the distance of the angles from a best setting, where it starts (locked); M is constant.
It prints one line per command it applies (``command R T ...``: the round trip it arrived
at, the wall-clock time [s]) and, at exit, ``commands N``.
"""

from __future__ import annotations

import math
import random
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout

STREAM = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                    depth=10000, durability=DurabilityPolicy.VOLATILE)
STATE = 'round_trip,E,M,O,energy,peak,alpha1,alpha2,alpha3,alpha_p'
BEST = (-0.39, -0.25, 0.52, -0.14)
LAG, SLEW, STEP, NOISE = 3, 0.1, math.radians(0.05), 0.01


def message(label: str, values: list[float]) -> Float64MultiArray:
    dim = MultiArrayDimension(label=label, size=len(values), stride=len(values))
    return Float64MultiArray(layout=MultiArrayLayout(dim=[dim]), data=values)


class MinimalDriver(Node):
    def __init__(self, rate: float) -> None:
        super().__init__('minimal_driver')
        self.round_trip, self.commands = 0, 0
        self.angles, self.target, self.wait = list(BEST), list(BEST), 0  # starts locked
        self.random = random.Random(1)
        self.state = self.create_publisher(Float64MultiArray, '/laser/state', STREAM)
        self.objective = self.create_publisher(Float64MultiArray, '/laser/objective', STREAM)
        self.create_subscription(Float64MultiArray, '/laser/angles_cmd', self.on_command,
                                 STREAM)
        self.create_timer(1.0 / rate, self.step)

    def on_command(self, msg: Float64MultiArray) -> None:
        data = list(msg.data)
        if len(data) != 4 or not all(math.isfinite(a) and abs(a) <= 2 * math.pi for a in data):
            return
        self.target, self.wait = data, LAG
        self.commands += 1
        print(f'command {self.round_trip} {time.time():.3f} {data}', flush=True)

    def step(self) -> None:
        self.round_trip += 1
        if self.wait:
            self.wait -= 1
        else:
            self.angles = [a + max(-SLEW, min(SLEW, t - a))
                           for a, t in zip(self.angles, self.target)]
        distance = sum(((a - b + math.pi / 2) % math.pi - math.pi / 2) ** 2
                       for a, b in zip(self.angles, BEST))
        e = 3.2 * math.exp(-distance / 0.1) * (1 + NOISE * self.random.gauss(0, 1))
        m = 18.0 * (1 + NOISE * self.random.gauss(0, 1))
        reported = [round(a / STEP) * STEP for a in self.angles]
        self.state.publish(message(STATE, [self.round_trip, e, m, e / m, e * e, e * e / 3,
                                           *reported]))
        self.objective.publish(message('O', [e / m]))


def main() -> None:
    rclpy.init()
    node = MinimalDriver(float(sys.argv[1]))
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        print(f'commands {node.commands}', flush=True)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
