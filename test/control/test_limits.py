import math

import numpy as np
import pytest

from dlmpc_ros.control.step import AngleLimits


def test_step_is_limited_and_goal_is_the_nearest_equivalent():
    limits = AngleLimits(-math.pi, math.pi, 0.1)
    got = limits.apply(np.zeros(4), np.array([0.05, 1.0, math.pi - 0.02, -3.0]))
    np.testing.assert_allclose(got, [0.05, 0.1, -0.02, 0.1], atol=1e-12)


def test_servo_goes_the_long_way_instead_of_leaving_the_range():
    limits = AngleLimits(-1.0, 2.5, 0.25)
    got = limits.apply(np.array([2.4, 0, 0, -0.9]), np.array([2.9, 0.1, -3.0, -1.3]))
    np.testing.assert_allclose(got, [2.15, 0.1, -3.0 + math.pi, -0.65], atol=1e-12)
    rng = np.random.default_rng(0)
    current = rng.uniform(-1.0, 2.5, 4)
    for _ in range(200):
        new = limits.apply(current, rng.uniform(-10, 10, 4))
        assert (new >= -1.0).all() and (new <= 2.5).all()
        assert np.abs(new - current).max() <= 0.25 + 1e-12
        current = new


@pytest.mark.parametrize('kwargs', [{'low': 1.0, 'high': 0.0}, {'max_step': 0.0},
                                    {'low': -math.inf}])
def test_bad_limits_are_rejected(kwargs):
    with pytest.raises(ValueError):
        AngleLimits(**kwargs)
