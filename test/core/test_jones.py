import numpy as np
import pytest

from dlmpc_ros.core.jones import (FROM_CIRCULAR, HALF_WAVE, POLARIZER, QUARTER_WAVE,
                                  TO_CIRCULAR, cavity_transfer, circular_transfer, rotated)

ANGLES = np.linspace(-3.0, 3.0, 13)


@pytest.mark.parametrize('plate', [QUARTER_WAVE, HALF_WAVE])
def test_rotated_plates_are_unitary(plate):
    j = rotated(plate, ANGLES)
    eye = np.broadcast_to(np.eye(2), j.shape)
    np.testing.assert_allclose(j @ np.conj(np.swapaxes(j, -1, -2)), eye, atol=1e-14)


def test_rotated_polarizer_is_a_projector():
    j = rotated(POLARIZER, ANGLES)
    np.testing.assert_allclose(j @ j, j, atol=1e-14)
    np.testing.assert_allclose(j, np.conj(np.swapaxes(j, -1, -2)), atol=1e-14)
    np.testing.assert_allclose(np.trace(j, axis1=-2, axis2=-1), 1.0, atol=1e-14)


def test_transfer_is_pi_periodic_in_every_angle():
    rng = np.random.default_rng(1)
    angles = rng.uniform(-2, 2, (20, 4))
    base = cavity_transfer(angles)
    for i in range(4):
        shifted = angles.copy()
        shifted[:, i] += np.pi
        np.testing.assert_allclose(cavity_transfer(shifted), base, atol=1e-13)


def test_transfer_order_half_wave_first():
    a = np.array([0.3, -0.7, 1.1, 0.4])
    expected = (rotated(QUARTER_WAVE, a[0]) @ rotated(POLARIZER, a[3])
                @ rotated(QUARTER_WAVE, a[1]) @ rotated(HALF_WAVE, a[2]))
    np.testing.assert_allclose(cavity_transfer(a), expected, atol=1e-15)


def test_circular_basis_round_trip():
    np.testing.assert_allclose(TO_CIRCULAR @ FROM_CIRCULAR, np.eye(2), atol=1e-15)
    a = np.array([0.3, -0.7, 1.1, 0.4])
    np.testing.assert_allclose(FROM_CIRCULAR @ circular_transfer(a) @ TO_CIRCULAR,
                               cavity_transfer(a), atol=1e-15)


def test_bad_angle_shape_is_rejected():
    with pytest.raises(ValueError, match='last dimension of 4'):
        cavity_transfer(np.zeros(3))
