"""Publishing a node's :class:`~dlmpc_ros.health.Health` on ``/diagnostics``.

One ``diagnostic_msgs/DiagnosticArray`` per second with one ``DiagnosticStatus`` (name:
the node's name, hardware_id ``dlmpc_ros``), which ``ros2 topic echo /diagnostics`` and
rqt_robot_monitor show. What goes in it is the node's business (a ``report`` callable);
this module only turns it into messages.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from dlmpc_ros import interfaces as itf
from dlmpc_ros.health import ERROR, Findings, Health
from dlmpc_ros.ros.io import DIAGNOSTICS_QOS

#: Seconds between two reports.
PERIOD = 1.0


class DiagnosticsPublisher:
    """Calls ``report(findings, now)`` (``now``: monotonic seconds) once a second and
    publishes the Health it returns; a report that raises is published as ERROR."""

    def __init__(self, node: Node, report: Callable[[Findings, float], Health],
                 hardware_id: str = 'dlmpc_ros') -> None:
        self._node = node
        self._report = report
        self._hardware_id = hardware_id
        self.started = time.monotonic()
        self._pub = node.create_publisher(DiagnosticArray, itf.TOPIC_DIAGNOSTICS,
                                          DIAGNOSTICS_QOS)
        node.create_timer(PERIOD, self.publish)

    def publish(self) -> None:
        try:
            health = self._report(Findings(), time.monotonic())
        except Exception as err:  # the report must not take the node down
            health = Health(ERROR, f'status report failed: {type(err).__name__}: {err}')
        status = DiagnosticStatus(level=bytes([health.level]), name=self._node.get_name(),
                                  message=health.message, hardware_id=self._hardware_id,
                                  values=[KeyValue(key=k, value=v) for k, v in health.values])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(msg)
