"""Controllers (no rclpy): the DL-MPC controller, its estimator, and baselines.

Every controller has the same runtime verb, ``step(measurement) -> ControlStep``: one
measurement ``(E, M, alpha1, alpha2, alpha3, alpha_p)`` per control period in, the
angles for the next period out. None of them ever receives the true birefringence.
"""
