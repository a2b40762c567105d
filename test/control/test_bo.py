"""The Bayesian-optimization baseline on a toy laser (a known pi-periodic O of the angles):
it stays in the limits, climbs, holds, restarts on a drop, repeats itself, and refuses bad
settings."""

import numpy as np
import pytest

from dlmpc_ros.control.bo import BOConfig, BOController, features
from dlmpc_ros.control.factory import make_controller
from dlmpc_ros.control.step import MODES, AngleLimits
from dlmpc_ros.paths import models_dir

OPTIMUM = np.array([0.4, -1.0, 1.2, -0.3])


def _objective(angles: np.ndarray, shift: float = 0.0) -> float:
    """0.2 at the optimum, pi-periodic in every angle, about 0.003 on average."""
    return float(0.2 * np.exp(2.0 * np.sum(np.cos(2 * (angles - OPTIMUM - shift)) - 1)))


def _drive(bo: BOController, periods: int, angles=None, shift=lambda t: 0.0):
    """Ideal servos: each period's O is measured at the angles commanded the period
    before."""
    angles = np.array([-1.2, 0.9, -0.4, 0.7]) if angles is None else angles
    seen, commands = [], []
    for t in range(periods):
        o = _objective(angles, shift(t))
        step = bo.step(np.array([o * 30.0, 30.0, *angles]))
        assert step.mode == 'bo' and np.isfinite(step.latency_ms)
        commands.append(step.angles)
        angles = step.angles
        seen.append(o)
    return angles, np.array(seen), np.array(commands)


def test_the_kernel_features_are_the_same_for_every_pi_equivalent_angle_set():
    a = np.array([0.3, -1.1, 2.0, 0.0])
    np.testing.assert_allclose(features(a), features(a + np.pi * np.array([1, -2, 3, 1])),
                               atol=1e-12)
    assert not np.allclose(features(a), features(a + np.pi / 2))


def test_bo_climbs_a_periodic_objective_within_the_limits_and_holds_it():
    limits = AngleLimits(low=-2.0, high=2.0, max_step=0.25)
    bo = BOController(BOConfig(lock_objective=0.1, seed=0), limits)
    angles, seen, commands = _drive(bo, 80)
    assert ((commands >= limits.low - 1e-12) & (commands <= limits.high + 1e-12)).all()
    assert np.abs(np.diff(commands, axis=0)).max() <= limits.max_step + 1e-12
    locked = np.flatnonzero(seen >= 0.1)
    # within a few dozen periods from ~0.003 (seeds 0-11: 16-60 periods, median 28)
    assert locked.size and locked[0] < 50
    assert bo.holding and bo.choices >= BOConfig().initial
    assert seen[-10:].min() >= 0.1  # it holds what it found
    assert MODES.index('bo') == 12  # appended after 'custom': older indices unchanged


def test_bo_restarts_when_the_objective_drops_and_finds_it_again():
    bo = BOController(BOConfig(lock_objective=0.1, restart_periods=3, seed=1))
    angles, _, _ = _drive(bo, 80)
    assert bo.holding and bo.restarts == 0
    shift = 0.7  # the optimum moves: the held O collapses
    angles, seen, _ = _drive(bo, 2, angles, shift=lambda t: shift)
    assert bo.restarts == 0 and bo.holding  # two low periods of three
    angles, seen, _ = _drive(bo, 1, angles, shift=lambda t: shift)
    assert bo.restarts == 1 and not bo.holding
    assert len(bo.objective) == 1  # the stale data forgotten, the latest kept
    _, seen, _ = _drive(bo, 100, angles, shift=lambda t: shift)
    assert seen.max() >= 0.1 and bo.holding


def test_bo_keeps_a_window_of_evaluations_and_skips_glitches():
    bo = BOController(BOConfig(window=12, initial=3, lock_objective=10.0, seed=2))
    _drive(bo, 40)
    assert len(bo.objective) == 12 and bo.angles.shape == (12, 4)
    n = bo.evaluations
    step = bo.step(np.array([np.nan, 30.0, 0.1, 0.2, 0.3, 0.4]))
    assert bo.evaluations == n and np.isfinite(step.angles).all()


def test_bo_is_deterministic_with_a_seed_and_built_by_name():
    def run(seed):
        return _drive(BOController(BOConfig(lock_objective=10.0, seed=seed)), 40)[2]

    np.testing.assert_array_equal(run(3), run(3))
    assert not np.array_equal(run(3), run(4))
    limits = AngleLimits(max_step=0.1)
    bo = make_controller('bo', models_dir(), limits)
    assert isinstance(bo, BOController) and bo.limits is limits


@pytest.mark.parametrize('bad', [{'window': 1}, {'initial': 0}, {'initial': 200},
                                 {'acquisition': 'pi'}, {'xi': -0.1}, {'candidates': 0},
                                 {'length_scale': 0.0}, {'noise': 2.0},
                                 {'restart_level': 0.0}, {'restart_keep': 150},
                                 {'lock_objective': float('nan')}, {'dwell': -1}])
def test_bad_bo_settings_are_rejected(bad):
    with pytest.raises(ValueError, match='BOConfig'):
        BOConfig(**bad)
