"""ROS 2 nodes of dlmpc_ros, one per module, each with a ``main``."""
