"""The DL-MPC's tracking curve: the best branch-continuous angles as a 1-D curve.

``models/track_curve.npz`` holds ``grid`` (n,), the curve parameter (a birefringence
estimate on the curve's own axis, in K's units), ``angles`` (n, 4) [rad], continuous
along the grid (pi-equivalents chosen next to each other), and ``objective`` (n,), the
steady O the simulator reached on the curve at each grid point, plus ``schema_version``.
It is made from the refined tracking path of the baseline tables (``models/oracle.npz``)
by ``dlmpc-train curve`` (or at the end of ``dlmpc-train baselines``;
:mod:`dlmpc_ros.training.stages.curve`). The controller
that loads it never learns the true K of a run: the curve is a map from an estimate to
angles, like the K-to-angles map.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.learning.tables import read_npz, write_npz

SCHEMA_VERSION = 1
FILE_NAME = 'track_curve.npz'
HINT = 'run `dlmpc-train curve` (from models/oracle.npz) to make it'


def check_curve(grid: np.ndarray, angles: np.ndarray, expected: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """A tracking curve as float arrays, checked: ``grid`` (n,) increasing, n >= 2,
    ``angles`` (n, 4) finite [rad], ``expected`` (n,) finite steady O or None.

    Raises ValueError saying what is wrong."""
    grid, angles = np.asarray(grid, float), np.asarray(angles, float)
    if grid.ndim != 1 or grid.size < 2 or angles.shape != (grid.size, 4) \
            or not np.all(np.diff(grid) > 0) or not np.all(np.isfinite(angles)):
        raise ValueError('a tracking curve needs an increasing grid (n >= 2) and finite '
                         f'(n, 4) angles; got {grid.shape} and {angles.shape}')
    if expected is not None:
        expected = np.asarray(expected, float)
        if expected.shape != grid.shape or not np.all(np.isfinite(expected)):
            raise ValueError(f'the expected O {expected.shape} of a tracking curve must be '
                             f'finite and fit its grid {grid.shape}')
    return grid, angles, expected


def save_curve(path: Path, curve: dict[str, np.ndarray], source: str) -> Path:
    """Write the curve (.npz, plain arrays) and a .json note of how it was made."""
    note = {'schema_version': SCHEMA_VERSION, 'made_by': 'dlmpc-train curve',
            'source': source, 'points': int(curve['grid'].size),
            'mean_objective': float(np.mean(curve['objective']))}
    return write_npz(path, curve, note)


def load_curve(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(grid (n,), angles (n, 4), objective (n,))`` of a curve file, checked.

    Raises FileNotFoundError when it is missing and ValueError when it cannot be read or
    is malformed; both say how to make it."""
    path = Path(path)
    arrays = read_npz(path, 'tracking curve', HINT)
    grid, angles, objective = (arrays.get(k) for k in ('grid', 'angles', 'objective'))
    if grid is None or angles is None or objective is None \
            or int(arrays.get('schema_version', -1)) != SCHEMA_VERSION:
        raise ValueError(f'tracking curve {path} lacks grid/angles/objective or has another '
                         f'schema; {HINT}')
    try:
        return check_curve(grid, angles, objective)
    except ValueError as err:
        raise ValueError(f'tracking curve {path} is malformed ({err}); {HINT}') from None


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
