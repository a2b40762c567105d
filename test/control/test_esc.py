import math

import numpy as np
import pytest

from dlmpc_ros.control.esc import ESCConfig, ESCController
from dlmpc_ros.control.step import MODES, AngleLimits

OPTIMUM = np.array([0.3, -0.2, 0.5, 0.1])
CURVATURE = np.array([0.6, 0.4, 0.1, 0.3])  # objective units per rad^2


def quadratic(angles: np.ndarray) -> float:
    """A smooth pi-periodic objective with its maximum 0.2 at OPTIMUM."""
    d = (angles - OPTIMUM + np.pi / 2) % np.pi - np.pi / 2
    return 0.2 - float(np.sum(CURVATURE * d * d))


def climb(controller: ESCController, angles: np.ndarray, periods: int) -> np.ndarray:
    for _ in range(periods):
        angles = controller.step(np.array([quadratic(angles), 1.0, *angles])).angles
    return angles


@pytest.mark.parametrize('normalize', ['none', 'log', 'mean'])
def test_climbs_a_quadratic_to_its_maximum(normalize):
    cfg = ESCConfig(amplitude=0.02, gain=0.05 if normalize == 'none' else 0.01,
                    normalize=normalize)
    controller = ESCController(np.zeros(4), cfg)
    start = quadratic(np.zeros(4))
    angles = climb(controller, np.zeros(4), 3000)
    np.testing.assert_allclose(controller.means, OPTIMUM, atol=0.03)
    assert quadratic(angles) > 0.199 > start
    assert controller.step(np.array([0.2, 1.0, *angles])).mode == 'esc'
    assert 'esc' in MODES


def test_first_measurement_sets_the_means_and_reset_forgets():
    controller = ESCController()
    start = np.array([0.1, 0.2, -0.3, 0.4])
    controller.step(np.array([0.1, 1.0, *start]))
    np.testing.assert_allclose(controller.means, start)
    climb(controller, start, 50)
    controller.reset()
    assert controller.means is None and controller.periods == 0
    assert not controller.gradient.any()


def test_commands_respect_range_and_servo_speed():
    limits = AngleLimits(-1.0, 2.5, 0.03)
    cfg = ESCConfig(amplitude=0.2, gain=5.0, max_mean_step=0.5)
    controller = ESCController(np.array([2.4, -0.9, 0.0, 1.0]), cfg, limits)
    rng = np.random.default_rng(0)
    angles = np.array([2.4, -0.9, 0.0, 1.0])
    for _ in range(500):
        o = float(rng.uniform(0.0, 0.3))
        new = controller.step(np.array([o, 1.0, *angles])).angles
        assert (new >= limits.low).all() and (new <= limits.high).all()
        assert np.abs(new - angles).max() <= limits.max_step + 1e-12
        angles = new


def test_non_finite_measurement_holds_the_angles_and_keeps_the_state_finite():
    controller = ESCController(np.zeros(4))
    angles = climb(controller, np.zeros(4), 100)
    means, gradient = controller.means.copy(), controller.gradient.copy()
    for bad in ([np.nan, 1.0], [1.0, 0.0], [np.inf, 2.0]):
        held = controller.step(np.array([*bad, *angles])).angles
        np.testing.assert_allclose(held, angles)
    np.testing.assert_array_equal(controller.means, means)
    np.testing.assert_array_equal(controller.gradient, gradient)
    held = controller.step(np.array([np.nan, np.nan, *[np.nan] * 4])).angles
    assert np.isfinite(held).all()
    angles = climb(controller, held, 2000)
    assert np.isfinite(controller.means).all() and np.isfinite(controller.gradient).all()
    assert quadratic(angles) > 0.19


@pytest.mark.parametrize('kwargs', [
    {'amplitude': 0.0}, {'amplitude': (0.01, 0.02)}, {'amplitude': math.nan},
    {'frequencies': (0.1, 0.2, 0.3)}, {'frequencies': (0.1, 0.1, 0.23, 0.37)},
    {'frequencies': (0.1, 0.2, 0.27, 0.41)},  # 0.2 = 2 x 0.1
    {'frequencies': (0.11, 0.17, 0.28, 0.6)},
    {'high_pass': 0.0}, {'low_pass': 1.5}, {'gain': -1.0}, {'normalize': 'sqrt'},
    {'max_mean_step': 0.0}])
def test_bad_settings_are_rejected_by_name(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=name):
        ESCConfig(**kwargs)


def test_bad_initial_angles_and_measurements_are_rejected():
    with pytest.raises(ValueError, match='initial_angles'):
        ESCController(np.zeros(3))
    with pytest.raises(ValueError, match='measurement'):
        ESCController().step(np.zeros(4))


def test_raises_the_laser_objective_in_a_short_closed_loop():
    from dlmpc_ros.core.drift import make_scenario
    from dlmpc_ros.evaluation.closed_loop import run_closed_loop

    # A mode-locked but detuned start (0.1 rad off the oracle angles for K = 0).
    start = np.array([0.71108170, -0.66734108, 1.55413490, -0.57867947])
    start = start + np.array([-0.1, 0.08, 0.1, -0.08])
    record = run_closed_loop(ESCController(), make_scenario('constant', offset=0.0), 3000,
                             initial_angles=start)
    o = np.nan_to_num(record.O, nan=0.0)
    assert o[-1000:].mean() > o[100:300].mean() + 0.005
    assert (record.mode == MODES.index('esc')).all()
