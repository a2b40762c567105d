"""dlmpc_ros: deep-learning model predictive control of a simulated mode-locked fiber laser."""

__version__ = '0.1.0'
