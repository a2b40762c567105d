"""QoS profiles and Float64MultiArray conversion used by every node.

What each topic promises (all reliable and volatile: a late joiner gets only new
messages). A reliable writer with a keep-last history drops a sample that a slow reader
has not acknowledged once ``depth`` newer ones follow, and Fast DDS repairs a lost sample
only at its next heartbeat (3 s by default, 0.1 s in the bringup's profile
``config/fastdds_loopback.xml``): the depth is what a reader may fall behind, or a repair
may take, without losing a message.

============================  ==================  ==============================================
topic                         history             promise
============================  ==================  ==============================================
/laser/state                  keep last 10000     every round trip reaches every reader that is
/laser/objective                                  less than 10000 messages (about 8 s at full
/laser/sim_truth                                  speed) behind
/laser/angles_cmd             keep last 10000     every command reaches the laser (applied in
                                                  order; the newest at each round trip wins)
/laser/birefringence          keep last 10000     every K reaches the simulator (likewise)
/estimator/birefringence      keep last 10000     one per decision, none missed
/controller/status            keep last 10000     same
/controller/measurement       keep last 10000     one per decision, none missed
/laser/status                 keep last 10        once a second; only the newest matters
/diagnostics                  keep last 10        likewise (diagnostic_msgs/DiagnosticArray,
                                                  every node; not in :data:`QOS`, whose
                                                  topics carry Float64MultiArray)
============================  ==================  ==============================================
"""

from __future__ import annotations

from collections.abc import Sequence

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout

from dlmpc_ros import interfaces

#: History depth of every topic that promises every message (see the table above).
STREAM_DEPTH = 10_000
STREAM_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        depth=STREAM_DEPTH, durability=DurabilityPolicy.VOLATILE)
STATUS_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST, depth=10,
                        durability=DurabilityPolicy.VOLATILE)
#: /diagnostics, as ROS diagnostics tools expect it.
DIAGNOSTICS_QOS = STATUS_QOS

QOS = {
    interfaces.TOPIC_STATE: STREAM_QOS,
    interfaces.TOPIC_OBJECTIVE: STREAM_QOS,
    interfaces.TOPIC_ANGLES_CMD: STREAM_QOS,
    interfaces.TOPIC_BIREFRINGENCE: STREAM_QOS,
    interfaces.TOPIC_SIM_TRUTH: STREAM_QOS,
    interfaces.TOPIC_LASER_STATUS: STATUS_QOS,
    interfaces.TOPIC_ESTIMATE: STREAM_QOS,
    interfaces.TOPIC_CONTROLLER_STATUS: STREAM_QOS,
    interfaces.TOPIC_MEASUREMENT: STREAM_QOS,
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
