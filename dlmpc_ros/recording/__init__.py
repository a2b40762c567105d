"""Recording runs as rosbag2 bags (MCAP storage, ROS 2 Jazzy format), without rclpy.

:mod:`~dlmpc_ros.recording.writer` writes already-serialized CDR messages into a bag that
a Jazzy ``ros2 bag info`` / ``ros2 bag play`` reads; :mod:`~dlmpc_ros.recording.reader`
loads a bag into numpy arrays per topic; :mod:`~dlmpc_ros.recording.repair` makes a bag
whose recorder was killed readable again; :mod:`~dlmpc_ros.recording.run_csv` is the
bringup's CSV record of a run, which :mod:`~dlmpc_ros.recording.export` also makes from a
bag.
"""

from dlmpc_ros.recording.reader import (
    BagTopic,
    RoundTripCheck,
    check_round_trips,
    read_bag,
    read_metadata,
)
from dlmpc_ros.recording.repair import RepairReport, repair
from dlmpc_ros.recording.writer import (
    FLOAT64_MULTI_ARRAY,
    METADATA_VERSION,
    BagError,
    BagWriter,
    make_qos,
)

__all__ = ['FLOAT64_MULTI_ARRAY', 'METADATA_VERSION', 'BagError', 'BagTopic', 'BagWriter',
           'RepairReport', 'RoundTripCheck', 'check_round_trips', 'make_qos', 'read_bag',
           'read_metadata', 'repair']
