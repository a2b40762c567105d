"""Angle arithmetic for the four pi-periodic Jones elements (radians, numpy only).

Every element of the cavity (the three waveplates and the polarizer) is pi-periodic in
its angle, so angle sets are compared and stored modulo pi.
"""

from __future__ import annotations

import math

import numpy as np


def wrap_angles(alpha: np.ndarray) -> np.ndarray:
    """Angles (any shape) wrapped into [-pi/2, pi/2)."""
    return (alpha + math.pi / 2) % math.pi - math.pi / 2


def angle_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between angle sets (..., 4), each element modulo pi."""
    return np.linalg.norm(wrap_angles(np.asarray(a, float) - np.asarray(b, float)), axis=-1)


def unwrap_table(angles: np.ndarray) -> np.ndarray:
    """A table of angles (n, 4) made continuous along its first axis: every row replaced
    by its pi-equivalent nearest to the row before."""
    angles = np.asarray(angles, float)
    steps = wrap_angles(np.diff(angles, axis=0))
    return np.concatenate([angles[:1], angles[:1] + np.cumsum(steps, axis=0)])
