"""Jones matrices of the waveplates and polarizer, and the cavity's transfer matrix.

Angles are in radians. Matrices act on the column ``[u; v]`` of the two linear
polarization envelopes. The solver works in the circular basis
``p = (u + i v)/sqrt(2)``, ``m = (u - i v)/sqrt(2)``, where the Kerr terms of the
model reduce to pure phase rotations; :data:`TO_CIRCULAR` converts.
"""

from __future__ import annotations

import numpy as np

QUARTER_WAVE = np.diag([np.exp(-0.25j * np.pi), np.exp(0.25j * np.pi)])
HALF_WAVE = np.diag([-1j, 1j])
POLARIZER = np.diag([1.0 + 0j, 0.0])

#: (2, 2) unitary: ``[p; m] = TO_CIRCULAR @ [u; v]``.
TO_CIRCULAR = np.array([[1.0, 1j], [1.0, -1j]]) / np.sqrt(2.0)
#: (2, 2) inverse of :data:`TO_CIRCULAR`.
FROM_CIRCULAR = TO_CIRCULAR.conj().T


def rotation(alpha: np.ndarray | float) -> np.ndarray:
    """Rotation matrices R(alpha), shape (..., 2, 2)."""
    alpha = np.asarray(alpha, dtype=float)
    c, s = np.cos(alpha), np.sin(alpha)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def rotated(element: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """The element ``J(W, alpha) = R(alpha) W R(alpha)^T`` for a (2, 2) ``W``; (..., 2, 2)."""
    r = rotation(alpha)
    return r @ element @ np.swapaxes(r, -1, -2)


def cavity_transfer(angles: np.ndarray) -> np.ndarray:
    """Transfer matrix applied after each fiber pass, in the linear basis.

    ``T = J(W_q, alpha1) J(W_p, alpha_p) J(W_q, alpha2) J(W_h, alpha3)``: the light meets
    the half-wave plate alpha3 first, then the quarter-wave plate alpha2, the polarizer
    alpha_p and the quarter-wave plate alpha1.

    Parameters
    ----------
    angles
        (..., 4) ``(alpha1, alpha2, alpha3, alpha_p)`` in radians.

    Returns
    -------
    (..., 2, 2) complex matrices.
    """
    angles = np.asarray(angles, dtype=float)
    if angles.shape[-1:] != (4,):
        raise ValueError(f'angles must have a last dimension of 4, got shape {angles.shape}')
    a1, a2, a3, ap = (angles[..., i] for i in range(4))
    return (rotated(QUARTER_WAVE, a1) @ rotated(POLARIZER, ap)
            @ rotated(QUARTER_WAVE, a2) @ rotated(HALF_WAVE, a3))


def circular_transfer(angles: np.ndarray) -> np.ndarray:
    """:func:`cavity_transfer` expressed in the circular basis, (..., 2, 2)."""
    return TO_CIRCULAR @ cavity_transfer(angles) @ FROM_CIRCULAR
