"""What the curve tracker learns of the laser in front of it: a rotation of the curve.

The tracking curve was made on the simulator's nominal cavity. On another laser (other
pump, loss, dispersion, gain bandwidth) the best angles move, and mostly they move
together: turning all four elements by one angle theta relative to the fiber's
birefringence axes recovers most of the gap (measured on the family plants the
controller's settings were chosen on: e.g. from 0.91 to 0.98 of that plant's envelope at
K = -0.25 on family plant 1). At K = 0, where the fiber is isotropic, such a turn changes
nothing, so theta matters more the larger |K| is and differs along the curve.

:class:`CurveRotation` is that correction as a function theta(u) of the curve parameter
``u``: piecewise linear on ``knots`` points, zero (the nominal curve) to begin with, and
turned at the ``u`` the tracker is at by the DL-MPC's rotation planner
(:mod:`dlmpc_ros.control.rotation_planner`). The mirror twin at estimate ``s`` is the
curve at ``u = -s`` turned by a quarter turn, so what is learned on one branch serves the
other.
"""

from __future__ import annotations

import numpy as np


class CurveRotation:
    """theta(u) [rad]: a learned turn of all four angles along the curve.

    ``low`` < ``high`` bound the curve parameter, ``knots`` >= 2 points carry the
    values, ``limit`` [rad] bounds |theta|.
    """

    def __init__(self, low: float, high: float, knots: int, limit: float) -> None:
        if not (np.isfinite([low, high]).all() and low < high and knots >= 2 and limit > 0):
            raise ValueError('need finite low < high, knots >= 2 and limit > 0')
        self.knots = np.linspace(low, high, knots)
        self.values = np.zeros(knots)
        self.limit = float(limit)
        self.updates = 0

    def __call__(self, u: float) -> float:
        """theta at ``u`` [rad] (u clipped to the knots' range)."""
        return float(np.interp(u, self.knots, self.values))

    def move(self, u: float, delta: float) -> None:
        """Change theta(u) by ``delta`` [rad], through the two knots around ``u`` (in
        proportion to their weights, so that theta(u) itself moves by ``delta``), within
        +-limit."""
        u = float(np.clip(u, self.knots[0], self.knots[-1]))
        right = int(np.clip(np.searchsorted(self.knots, u), 1, self.knots.size - 1))
        w_right = (u - self.knots[right - 1]) / (self.knots[right] - self.knots[right - 1])
        weights = np.array([1.0 - w_right, w_right])
        change = delta * weights / float(np.sum(weights ** 2))
        index = [right - 1, right]
        self.values[index] = np.clip(self.values[index] + change, -self.limit, self.limit)
        self.updates += 1
