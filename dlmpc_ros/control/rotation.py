"""What the curve tracker learns of the laser in front of it: a rotation of the curve.

On a laser other than the simulator's nominal cavity the best angles move, mostly together:
turning all four elements by one angle theta recovers most of the gap. :class:`CurveRotation`
is theta(u) along the curve (it does nothing at K = 0, more the larger |K|), turned by the
rotation planner (:mod:`dlmpc_ros.control.rotation_planner`). The twin at estimate ``s`` is
the curve at ``u = -s`` turned a quarter turn, so one rotation serves both branches.
"""

from __future__ import annotations

import numpy as np


class CurveRotation:
    """theta(u) [rad]: a learned turn of all four angles along the curve.

    ``low`` < ``high`` bound the curve parameter (K units), ``knots`` >= 2 points carry
    the values, ``limit`` [rad] bounds |theta|, ``spread`` (0: off) is :meth:`move`'s prior.
    """

    def __init__(self, low: float, high: float, knots: int, limit: float,
                 spread: float = 0.0) -> None:
        if not (np.isfinite([low, high]).all() and low < high and knots >= 2 and limit > 0
                and spread >= 0):
            raise ValueError('need finite low < high, knots >= 2, limit > 0 and spread >= 0')
        self.spread = float(spread)
        self.knots = np.linspace(low, high, knots)
        self.values = np.zeros(knots)
        #: knots a move was planned next to (their own evidence)
        self.explored = np.zeros(knots, bool)
        self.limit = float(limit)
        self.updates = 0

    def start_from(self, knots: np.ndarray, values: np.ndarray) -> None:
        """Begin from a calibrated rotation, ``values`` [rad] at ``knots`` (within +-limit)."""
        self.values = np.clip(np.interp(self.knots, knots, values), -self.limit, self.limit)

    def __call__(self, u: float) -> float:
        """theta at ``u`` [rad] (u clipped to the knots' range)."""
        return float(np.interp(u, self.knots, self.values))

    def move(self, u: float, delta: float) -> None:
        """Change theta(u) by ``delta`` [rad] through the two knots around ``u``, within
        +-limit. With ``spread`` > 0 every unexplored knot first moves by ``delta`` x
        exp(-(knot - u)^2 / (2 spread^2)), and the two knots by what theta(u) still lacks."""
        u = float(np.clip(u, self.knots[0], self.knots[-1]))
        right = int(np.clip(np.searchsorted(self.knots, u), 1, self.knots.size - 1))
        w_right = (u - self.knots[right - 1]) / (self.knots[right] - self.knots[right - 1])
        weights = np.array([1.0 - w_right, w_right])
        change = delta * weights / float(np.sum(weights ** 2))
        index = [right - 1, right]
        if self.spread > 0 and delta:  # the unexplored knots, then the rest at u's two
            shared = delta * np.exp(-0.5 * ((self.knots - u) / self.spread) ** 2)
            shared[self.explored] = 0.0
            self.values = np.clip(self.values + shared, -self.limit, self.limit)
            change = change * (1.0 - float(np.interp(u, self.knots, shared)) / delta)
        self.values[index] = np.clip(self.values[index] + change, -self.limit, self.limit)
        self.explored[index] |= weights > 0
        self.updates += 1


def locate(angles: np.ndarray, grid: np.ndarray, curve: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where angle sets ``angles`` (n, 4) [rad] lie on the rotated curve (``grid`` (m,),
    ``curve`` (m, 4)) and its twin: the grid point ``u`` and rotation ``theta`` [rad] that
    fit each best (modulo pi, the half-wave plate modulo pi/2; beyond +-pi/4: the twin,
    ``branch`` -1, ``theta`` less a quarter turn). Returns ``(branch, u, theta, misfit)``,
    each (n,), the misfit the RMS angle difference left [rad]."""
    angles = np.asarray(angles, float)[:, None, :]                 # (n, 1, 4)
    residual = angles - np.asarray(curve, float)[None]             # (n, m, 4)
    pi_periodic = residual[..., [0, 1, 3]]
    theta = 0.5 * np.arctan2(np.sin(2 * pi_periodic).sum(-1),
                             np.cos(2 * pi_periodic).sum(-1))      # (n, m), mod pi
    left = residual - theta[..., None]
    left[..., [0, 1, 3]] = (left[..., [0, 1, 3]] + np.pi / 2) % np.pi - np.pi / 2
    left[..., 2] = (left[..., 2] + np.pi / 4) % (np.pi / 2) - np.pi / 4
    misfit = np.sqrt(np.mean(left ** 2, axis=-1))                   # (n, m)
    best = np.argmin(misfit, axis=1)
    rows = np.arange(best.size)
    theta = theta[rows, best]
    twin = np.abs(theta) > np.pi / 4
    theta = np.where(twin, theta - np.sign(theta) * np.pi / 2, theta)
    return (np.where(twin, -1, 1), np.asarray(grid, float)[best], theta, misfit[rows, best])
