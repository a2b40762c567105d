"""The toy tracking curve the control tests share: 61 points over K in [-0.3, 0.3]."""

import numpy as np

GRID = np.linspace(-0.3, 0.3, 61)
#: A toy curve whose first angle is twice its parameter, so a command tells its s.
ANGLES = np.stack([2 * GRID, 0.1 + 0 * GRID, -0.2 + GRID, 0.3 + 0 * GRID], axis=1)


def toy_curve(steady_objective: float = 0.2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The controller's ``curve`` argument: (grid, angles, steady O) on the toy curve."""
    return GRID, ANGLES, np.full(len(GRID), steady_objective)
