"""The cavity's exact mirror symmetry: (K, angles, u, v) and its twin run alike."""

import numpy as np

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.core.symmetry import mirror_angles, mirror_fields

NAMES = ('E', 'M', 'O', 'energy', 'peak')


def _twins(angles, k, u, v) -> tuple[Cavity, Cavity]:
    laser = Cavity(batch=len(k), angles=angles, birefringence=k)
    twin = Cavity(batch=len(k), angles=mirror_angles(angles), birefringence=-k)
    laser.set_fields(u, v)
    twin.set_fields(*mirror_fields(u, v))
    return laser, twin


def test_a_laser_and_its_mirror_twin_agree_from_random_angles_k_and_fields():
    rng = np.random.default_rng(3)
    batch, n = 8, 256
    angles = rng.uniform(-np.pi / 2, np.pi / 2, (batch, 4))
    k = rng.uniform(-0.3, 0.3, batch)
    u, v = ((rng.standard_normal((batch, n)) + 1j * rng.standard_normal((batch, n))) * 0.7
            for _ in range(2))
    laser, twin = _twins(angles, k, u, v)
    a, b = laser.run(50), twin.run(50)
    for name in NAMES:  # equal but for rounding (some of these starts are chaotic)
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-12,
                                   atol=1e-12, err_msg=name)


def test_a_steady_state_and_its_twin_stay_together():
    k = np.array([0.1, 0.0])
    angles = np.array([[-0.39, -0.25, 0.52, -0.14], [-0.35, -0.25, 0.5, -0.1]])
    start = Cavity(batch=2, angles=angles, birefringence=k)
    assert run_to_steady(start, 600, 5).converged.all()
    laser, twin = _twins(angles, k, *start.fields())
    a, b = laser.run(300), twin.run(300)
    for name in NAMES:
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-12,
                                   atol=1e-12, err_msg=name)
    ua, va = laser.fields()
    ub, vb = twin.fields()
    np.testing.assert_allclose(ub, va, atol=1e-10)
    np.testing.assert_allclose(vb, -ua, atol=1e-10)


def test_the_spec_pulse_mirrors_to_another_start():
    """u = v = sech turns into u = -v: a cold start at K and at -K can end apart."""
    laser = Cavity(batch=1, angles=np.array([-0.39, -0.25, 0.52, -0.14]), birefringence=0.1)
    u, v = laser.fields()
    mu, mv = mirror_fields(u, v)
    np.testing.assert_allclose(mu, -mv)
    assert not np.allclose(mv, v)
