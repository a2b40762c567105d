"""Physics, drift and (later) learning/control core of dlmpc_ros; never imports rclpy."""
