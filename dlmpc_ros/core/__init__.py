"""Physics and drift (numpy, numba; no torch, no rclpy): the cavity model and its solver,
the drift scenarios, angle arithmetic and the checks shared by settings dataclasses."""
