"""The parameters every controller node shares (:mod:`~dlmpc_ros.ros.controller_base`):
defaults, descriptions and ranges, and the start-up checks that turn them into the
servo limits and the period's measurement."""

from __future__ import annotations

from dlmpc_ros.control.step import (MEASUREMENT_ROUND_TRIPS, SETTLE_TIMEOUT, SETTLE_TOLERANCE,
                                    AngleLimits, PeriodMeasurement)
from dlmpc_ros.ros import params

COMMON_DEFAULTS: dict[str, object] = {
    'period': 10, 'angle_low': AngleLimits.low, 'angle_high': AngleLimits.high,
    'max_step': AngleLimits.max_step,
    'models_dir': '', 'estimator_timeout': 0.5,
    'measurement_round_trips': MEASUREMENT_ROUND_TRIPS,
    'settle_tolerance': SETTLE_TOLERANCE, 'settle_timeout': SETTLE_TIMEOUT,
}
COMMON_DESCRIPTIONS = {
    'period': 'control period P [round trips]: the least time between two decisions',
    'angle_low': 'lowest angle the servos may be sent to [rad]',
    'angle_high': 'highest angle the servos may be sent to [rad]',
    'max_step': 'largest angle change per control period [rad] (servo speed)',
    'models_dir': 'directory of the model files (empty: the installed models/)',
    'estimator_timeout': 'seconds to wait for the estimate of a period before acting '
                         'without it (a controller that reads it: strategy:=paper)',
    'measurement_round_trips': "a period's measurement is the mean E and M of the last this "
                               "many round trips at its angles (1: its own round trip only; "
                               "more divide a detector's noise)",
    'settle_tolerance': 'a state counts for a decision once every reported angle is within '
                        'this of the command [rad] (above the encoder\'s noise and step)',
    'settle_timeout': 'round trips after a decision by which the next one is made even if '
                      'the servos have not settled (with a warning)',
}

#: Ranges (``ros2 param describe`` shows them; rclpy refuses values outside).
COMMON_RANGES: dict[str, tuple[float, float]] = {
    'period': (1, 1_000_000), 'angle_low': (-1e3, 1e3), 'angle_high': (-1e3, 1e3),
    'max_step': (1e-9, 1e3), 'estimator_timeout': (1e-3, 3600.0),
    'measurement_round_trips': (1, 10_000),  # the states a period keeps for its mean
    'settle_tolerance': (0.0, 1.0), 'settle_timeout': (1, 1_000_000_000),
}


def period_measurement_from(values: dict) -> PeriodMeasurement:
    """The node's :class:`PeriodMeasurement` from its ``period``,
    ``measurement_round_trips``, ``settle_tolerance`` and ``settle_timeout`` parameters;
    StartupError naming the problem."""
    try:
        return PeriodMeasurement(values['period'], values['measurement_round_trips'],
                                 values['settle_tolerance'], values['settle_timeout'])
    except ValueError as err:
        raise params.StartupError(str(err)) from None


def limits_from(values: dict) -> AngleLimits:
    """AngleLimits from the node's parameters; StartupError naming the problem."""
    if not (isinstance(values['period'], int) and values['period'] >= 1):
        raise params.StartupError(f"period must be an integer >= 1, got {values['period']}")
    if not values['estimator_timeout'] > 0:
        raise params.StartupError('estimator_timeout must be > 0 s')
    try:
        return AngleLimits(values['angle_low'], values['angle_high'], values['max_step'])
    except ValueError as err:
        raise params.StartupError(str(err)) from None
