"""The learned models and their files (torch, no rclpy): the VAE estimator, the
K-to-angles map, the MP-RNN predictor, the angle tables and tracking curve the controller
loads, and the one fitting loop they share. Making data and training them is
:mod:`dlmpc_ros.training`."""
