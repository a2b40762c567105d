"""The searches the data and table builders share (numpy; angles in radians).

- :func:`steady_scores`: the steady objective of a batch of lasers, warm-started;
- :func:`compass_search`: a batched compass (pattern) search uphill on the steady O,
  each laser at its own K, warm-started from its best field;
- :func:`best_path`: the best sequence of one candidate per step, by dynamic programming
  (the tracking path over the K grid, the K-to-angles map's training subset).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.steady import run_to_steady

#: The compass directions: +-1 along each of the four angles, (8, 4).
DIRECTIONS = np.concatenate([np.eye(4), -np.eye(4)])
#: Gain in O a compass move must bring to be taken.
MIN_GAIN = 1e-7

Fields = tuple[np.ndarray, np.ndarray]


def steady_scores(cavity_cfg: CavityConfig | None, angles: np.ndarray, k: np.ndarray,
                  fields: Fields | None = None, cap: int = 300, chunk: int = 5
                  ) -> tuple[np.ndarray, Fields]:
    """Steady O (B,) of lasers at ``angles`` (B, 4) and ``k`` (B,), started from
    ``fields`` (u, v) (B, n) or the spec's initial pulse; -inf where a laser did not
    converge within ``cap`` round trips or blew up. Also returns the final fields."""
    cavity = Cavity(cavity_cfg, batch=angles.shape[0], angles=angles, birefringence=k)
    if fields is not None:
        cavity.set_fields(*fields)
    result = run_to_steady(cavity, cap, chunk)
    return np.where(result.converged & result.finite, result.O, -np.inf), cavity.fields()


@dataclass(frozen=True)
class CompassResult:
    """Where a compass search ended, per laser (n,)."""

    angles: np.ndarray
    """(n, 4) best angles [rad]."""
    objective: np.ndarray
    """(n,) their steady O."""
    u: np.ndarray
    """(n, points) linear-basis field u of the best state."""
    v: np.ndarray
    """(n, points) field v of the best state."""
    iterations: int
    """Compass iterations run (all lasers move at once)."""


def compass_search(angles: np.ndarray, k: np.ndarray, objective: np.ndarray, fields: Fields,
                   cavity_cfg: CavityConfig | None, *, first_step: float, min_step: float,
                   max_iterations: int, cap: int, chunk: int, wrap: bool,
                   progress: Callable[[int, float, int], None] | None = None
                   ) -> CompassResult:
    """Move every laser's angles (n, 4) uphill on its steady O at its own ``k`` (n,).

    Each iteration tries +-step on every angle (8 neighbours per laser, warm-started from
    the laser's best field) and takes the best converged neighbour if it gains more than
    :data:`MIN_GAIN`; otherwise the laser's step halves, down to ``min_step``.
    ``objective`` (n,) and ``fields`` (u, v) are those of the starting angles. ``wrap``
    keeps the trial angles in [-pi/2, pi/2) (else they move freely, continuous along a
    branch). ``progress(iteration, mean O, lasers still moving)`` after each iteration.
    """
    best_a = np.array(angles, float)
    best_o = np.array(objective, float)
    best_u, best_v = (np.array(f) for f in fields)
    n = best_a.shape[0]
    lanes = np.arange(n)
    step = np.full(n, first_step)
    iterations = 0
    while (step >= min_step).any() and iterations < max_iterations:
        iterations += 1
        trial = best_a[:, None, :] + step[:, None, None] * DIRECTIONS   # (n, 8, 4)
        if wrap:
            trial = wrap_angles(trial)
        score, (u, v) = steady_scores(cavity_cfg, trial.reshape(-1, 4), np.repeat(k, 8),
                                      (np.repeat(best_u, 8, axis=0),
                                       np.repeat(best_v, 8, axis=0)), cap, chunk)
        score = score.reshape(n, 8)
        j = score.argmax(axis=1)
        better = (score[lanes, j] > best_o + MIN_GAIN) & (step >= min_step)
        rows = lanes * 8 + j
        best_a[better] = trial[better, j[better]]
        best_o[better] = score[better, j[better]]
        best_u[better], best_v[better] = u[rows][better], v[rows][better]
        step[~better] /= 2
        if progress is not None:
            progress(iterations, float(best_o.mean()), int((step >= min_step).sum()))
    return CompassResult(best_a, best_o, best_u, best_v, iterations)


def best_path(values: Sequence[np.ndarray], cost: Callable[[int], np.ndarray]) -> list[int]:
    """One candidate per step maximizing the summed values minus the transition costs.

    ``values[i]`` (n_i,) are the candidates' values at step i; ``cost(i)`` (n_{i-1}, n_i)
    is the cost of going from each candidate of step i - 1 to each of step i. Returns
    the chosen candidate index of every step (ties go to the lower index).
    """
    score = np.array(values[0], float)
    back: list[np.ndarray] = []
    for i in range(1, len(values)):
        total = score[:, None] - cost(i)                                # (previous, now)
        back.append(total.argmax(axis=0))
        score = values[i] + total.max(axis=0)
    pick = [int(np.argmax(score))]
    for i in range(len(values) - 1, 0, -1):
        pick.append(int(back[i - 1][pick[-1]]))
    return pick[::-1]
