"""The estimator check tells a surrogate that reads the laser from one that reads the angles."""

import numpy as np
import pytest

from dlmpc_ros.learning.features import Normalizer
from dlmpc_ros.evaluation.identifiability import ProbeConfig, abs_r, probe_r, surrogate_sources


def _measurements(k: np.ndarray, angles_follow_k: bool, rng) -> np.ndarray:
    """(N, 6) measurements whose E follows K; the angles follow K only if asked (as the
    trajectories' data policy does), else they are independent of it (as in the sweep)."""
    n = k.size
    alpha = rng.uniform(-1.5, 1.5, (n, 4))
    if angles_follow_k:
        alpha[:, 0] = 2.0 * k + 0.05 * rng.standard_normal(n)
    energy = 5.0 + 8.0 * k + 0.1 * rng.standard_normal(n)
    kurtosis = rng.uniform(20.0, 200.0, n)
    return np.column_stack([energy, kurtosis, alpha])


def test_abs_r_is_zero_for_a_constant_series():
    assert abs_r(np.ones(5), np.arange(5.0)) == 0.0
    assert abs_r(-np.arange(5.0), np.arange(5.0)) == pytest.approx(1.0)


def test_sources_separate_angle_readback_from_measurement():
    rng = np.random.default_rng(0)
    k_traj, k_sweep = rng.uniform(-0.3, 0.3, 3000), rng.uniform(-0.3, 0.3, 3000)
    traj = _measurements(k_traj, True, rng)
    sweep = _measurements(k_sweep, False, rng)

    reads_angles = surrogate_sources(lambda m: m[:, 2], traj, k_traj, sweep, k_sweep)
    assert reads_angles['trajectories'] > 0.9
    assert reads_angles['trajectories_angles_only'] > 0.9
    assert reads_angles['trajectories_E_M_only'] < 0.1
    assert reads_angles['sweep'] < 0.1

    reads_energy = surrogate_sources(lambda m: m[:, 0], traj, k_traj, sweep, k_sweep)
    assert reads_energy['trajectories_angles_only'] < 0.1
    assert reads_energy['trajectories_E_M_only'] > 0.9
    assert reads_energy['sweep'] > 0.9


def test_supervised_probe_finds_k_only_where_it_is():
    rng = np.random.default_rng(1)
    k = rng.uniform(-0.3, 0.3, 3000)
    measured = _measurements(k, False, rng)
    train = rng.random(k.size) < 0.8
    norm = Normalizer.fit(measured[:, 0], measured[:, 1])
    config = ProbeConfig(hidden=32, epochs=5)
    assert probe_r(measured, k, train, norm, 'E_M', config) > 0.9
    assert probe_r(measured, k, train, norm, 'angles', config) < 0.2
