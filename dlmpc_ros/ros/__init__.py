"""The thin ROS 2 layer: QoS profiles, message conversion and parameter helpers."""
