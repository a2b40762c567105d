import math

import numpy as np
from numba import njit

from dlmpc_ros.core.kernels import cos_sin


@njit
def _table(theta):
    out = np.empty((theta.shape[0], 2))
    for i in range(theta.shape[0]):
        out[i, 0], out[i, 1] = cos_sin(theta[i])
    return out


def test_polynomial_cos_sin_matches_libm():
    theta = np.concatenate([np.linspace(-50, 50, 200001), [0.0, math.pi / 4, math.pi / 2, 1e4]])
    got = _table(theta)
    np.testing.assert_allclose(got[:, 0], np.cos(theta), rtol=0, atol=3e-16 * 8)
    np.testing.assert_allclose(got[:, 1], np.sin(theta), rtol=0, atol=3e-16 * 8)
