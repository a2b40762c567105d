"""QoS profiles and Float64MultiArray conversion used by every node.

QoS of each topic (all volatile, so a late joiner gets only new messages):

============================  ==========  ===========  ======================================
topic                          reliability  history      why
============================  ==========  ===========  ======================================
/laser/state                   reliable    keep last 1000  a subscriber that keeps up never
                                                        misses a round trip, even in bursts
/laser/objective               reliable    keep last 1000  same, for ``ros2 topic echo``
/laser/angles_cmd              reliable    keep last 10    commands are never silently lost
/laser/birefringence           reliable    keep last 10    same
/laser/sim_truth               reliable    keep last 1000  like /laser/state (simulator only)
/laser/status                  reliable    keep last 10    once a second
/estimator/birefringence       reliable    keep last 1000  one per control period, none missed
/controller/status             reliable    keep last 1000  same
============================  ==========  ===========  ======================================
"""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout

from dlmpc_ros import interfaces

STREAM_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        depth=1000, durability=DurabilityPolicy.VOLATILE)
COMMAND_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_LAST, depth=10,
                         durability=DurabilityPolicy.VOLATILE)

QOS = {
    interfaces.TOPIC_STATE: STREAM_QOS,
    interfaces.TOPIC_OBJECTIVE: STREAM_QOS,
    interfaces.TOPIC_ANGLES_CMD: COMMAND_QOS,
    interfaces.TOPIC_BIREFRINGENCE: COMMAND_QOS,
    interfaces.TOPIC_SIM_TRUTH: STREAM_QOS,
    interfaces.TOPIC_LASER_STATUS: COMMAND_QOS,
    interfaces.TOPIC_ESTIMATE: STREAM_QOS,
    interfaces.TOPIC_CONTROLLER_STATUS: STREAM_QOS,
}


def layout_for(fields: Sequence[str]) -> MultiArrayLayout:
    """A one-dimensional layout whose label lists the field names."""
    return MultiArrayLayout(dim=[MultiArrayDimension(label=','.join(fields), size=len(fields),
                                                     stride=len(fields))], data_offset=0)


def vector_message(fields: Sequence[str], values: Sequence[float]) -> Float64MultiArray:
    """A labelled Float64MultiArray; values must match fields in length."""
    if len(values) != len(fields):
        raise ValueError(f'{len(values)} values for {len(fields)} fields {tuple(fields)}')
    return Float64MultiArray(layout=layout_for(fields), data=[float(x) for x in values])
