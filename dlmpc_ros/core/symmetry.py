"""The cavity's mirror symmetry (exact: E, M and O agree to 1e-14 over many round trips).

The model maps onto itself under

    (K, alpha1, alpha2, alpha3, alpha_p, u, v) -> (-K, alpha1 + pi/2, alpha2 + pi/2, alpha3,
                                                   alpha_p + pi/2, v, -u)

the field turned by 90 degrees: the fiber equations swap u and v with the sign of K, and
turning every element by pi/2 conjugates the Jones matrices by the same rotation (the
half-wave plate only changes a global sign, so alpha3 stays). Every steady state at K has
a twin at -K with the same E, M and O, reached from the turned field. The spec's initial
pulse ``u = v = sech`` turns into ``u = -v = sech``, another start: a cold start from the
pulse can land on different attractors at K and at -K, so the envelope takes, at each K,
the better of its own search and the mirror of the search at -K.
"""

from __future__ import annotations

import math

import numpy as np

#: What the mirror adds to ``(alpha1, alpha2, alpha3, alpha_p)`` [rad].
ANGLE_SHIFT = np.array([math.pi / 2, math.pi / 2, 0.0, math.pi / 2])
#: A quarter turn [rad]. Turning all four elements by it is the mirror too (the half-wave
#: plate turned by pi/2 only flips the field's sign), and at K = 0, where the fiber is
#: isotropic, turning all four together by any angle maps steady states onto steady
#: states: a laser keeps its pulse while its servos turn from one twin to the other.
QUARTER_TURN = math.pi / 2
#: Index of the half-wave plate's angle alpha3 in an angle set: the plate turned by a quarter
#: turn only flips the field's sign, so alpha3 and alpha3 + pi/2 are one setting.
HALF_WAVE = 2


def mirror_angles(angles: np.ndarray) -> np.ndarray:
    """The twin's angles (..., 4) [rad] (not wrapped)."""
    return np.asarray(angles, float) + ANGLE_SHIFT


def mirror_fields(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The twin's linear-basis fields ``(v, -u)`` (the field turned by 90 degrees)."""
    return np.asarray(v), -np.asarray(u)
