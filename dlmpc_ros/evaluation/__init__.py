"""Closed-loop evaluation (no rclpy): run records, the in-process loop, metrics, figures."""
