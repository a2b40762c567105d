"""The VAE estimator's surrogates for a controller node whose controller reads them (the
paper's loops, ``uses_estimator``): /controller/estimate by round trip
(:class:`EstimateInbox`), and the wait at start for the estimator to read
/controller/measurement (:func:`subscribe_when_heard`), so that the first decision does not
wait for an estimate that cannot come.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from rclpy.node import Node
from rclpy.publisher import Publisher
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf

#: Longest wait at start for the estimator to read /controller/measurement [s].
ESTIMATOR_WAIT = 3.0
#: Surrogates kept, the latest round trips'.
KEEP = 64


class EstimateInbox:
    """The latest surrogates by round trip (a malformed message is logged by ``warn`` and
    dropped)."""

    def __init__(self, warn: itf.RateLimitedLog) -> None:
        self._warn = warn
        self._by_round_trip: dict[int, float] = {}
        self.last_heard: float | None = None  # monotonic time of the latest [s]
        self.latest_round_trip: int | None = None

    def add(self, msg: Float64MultiArray) -> bool:
        """A /controller/estimate message; whether it was kept."""
        data = msg.data
        fault = None
        if len(data) < len(itf.ESTIMATE_FIELDS):
            fault = f'expected at least {len(itf.ESTIMATE_FIELDS)} values, got {len(data)}'
        elif not all(math.isfinite(x) and abs(x) < 1e300 for x in data):
            fault = 'non-finite or out-of-range value'
        elif data[0] < 0 or data[0] != int(data[0]):
            fault = f'round_trip = {data[0]} is not a count'
        if fault is not None:
            self._warn.dropped(itf.TOPIC_ESTIMATE, fault)
            return False
        round_trip = int(data[0])
        self.last_heard = time.monotonic()
        self._by_round_trip[round_trip] = float(data[1])
        self.latest_round_trip = round_trip
        while len(self._by_round_trip) > KEEP:
            self._by_round_trip.pop(next(iter(self._by_round_trip)))
        return True

    def surrogate(self, round_trip: int) -> float | None:
        """The surrogate for round trip r's measurement (None: not here)."""
        return self._by_round_trip.get(round_trip)

    def age(self, round_trip: int, period: int) -> float:
        """Periods from the latest estimate's round trip to ``round_trip`` (-1: none yet)."""
        if self.latest_round_trip is None:
            return -1.0
        return (round_trip - self.latest_round_trip) / period


def subscribe_when_heard(node: Node, measurement_pub: Publisher,
                         subscribe: Callable[[], None]) -> None:
    """Call ``subscribe()`` once the estimator reads ``measurement_pub``, or after
    ``ESTIMATOR_WAIT`` s without it (with a warning: the controller holds until it does)."""
    waiting_since = time.monotonic()

    def check() -> None:
        heard = measurement_pub.get_subscription_count() > 0
        if heard or time.monotonic() - waiting_since > ESTIMATOR_WAIT:
            if not heard:
                node.get_logger().warning(
                    f'no estimator reads {itf.TOPIC_MEASUREMENT} after '
                    f'{ESTIMATOR_WAIT:g} s; controlling without it until it does')
            timer.cancel()
            subscribe()
    timer = node.create_timer(0.02, check)
