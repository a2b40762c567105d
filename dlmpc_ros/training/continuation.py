"""Steady states along an angle table by continuation in K, as a slowly drifting laser
would meet them: each laser warm-starts from its previous steady state (numpy)."""

from __future__ import annotations

import numpy as np

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.steady import run_to_steady


def follow_path(k_grid: np.ndarray, angles: np.ndarray, order: np.ndarray,
                cavity_cfg: CavityConfig | None = None, first_cap: int = 300, cap: int = 100,
                chunk: int = 5) -> dict[str, np.ndarray]:
    """Steady states along angle tables by continuation, one laser per row of ``order``.

    Laser b starts from the spec's initial pulse at K index ``order[b, 0]`` and moves
    through the K indices ``order[b, 1:]``, warm-started from its previous steady state
    (up to ``first_cap`` round trips at the first point, ``cap`` at the others).
    ``angles`` is one table (n_k, 4) for every laser or one per laser (B, n_k, 4).

    Returns ``O`` and ``converged`` (B, L) per visited point (O = 0 where the field blew
    up; the laser then restarts from the initial pulse) and the linear-basis fields
    ``u``, ``v`` (B, L, n) of every steady state.
    """
    order = np.atleast_2d(np.asarray(order, int))
    batch, length = order.shape
    tables = np.broadcast_to(np.asarray(angles, float), (batch, k_grid.size, 4))
    lanes = np.arange(batch)
    cavity = Cavity(cavity_cfg, batch=batch, angles=tables[lanes, order[:, 0]],
                    birefringence=k_grid[order[:, 0]])
    o = np.zeros((batch, length))
    converged = np.zeros((batch, length), bool)
    u_all = np.empty((batch, length, cavity.grid.points), np.complex128)
    v_all = np.empty_like(u_all)
    for step in range(length):
        cavity.set_angles(tables[lanes, order[:, step]])
        cavity.set_birefringence(k_grid[order[:, step]])
        result = run_to_steady(cavity, first_cap if step == 0 else cap, chunk)
        o[:, step] = np.where(result.finite, np.nan_to_num(result.O), 0.0)
        converged[:, step] = result.converged & result.finite
        u_all[:, step], v_all[:, step] = cavity.fields()
        if not result.finite.all():
            cavity.reset(np.flatnonzero(~result.finite))
    return {'O': o, 'converged': converged, 'u': u_all, 'v': v_all}


def round_trip_orders(n_k: int, start: int) -> np.ndarray:
    """Two K index orders (2, 2 n_k - 1) from ``start``: up to the end, down to 0 and back
    to ``start``; and down to 0, up to the end and back to ``start``."""
    up_first = np.concatenate([np.arange(start, n_k), np.arange(n_k - 2, -1, -1),
                               np.arange(1, start + 1)])
    down_first = np.concatenate([np.arange(start, -1, -1), np.arange(1, n_k),
                                 np.arange(n_k - 2, start - 1, -1)])
    return np.stack([up_first, down_first])


def continuation_check(k_grid: np.ndarray, angles: np.ndarray,
                       cavity_cfg: CavityConfig | None = None, start_k: float = 0.0,
                       cap: int = 100, chunk: int = 5) -> dict[str, np.ndarray]:
    """Steady O along a table (n_k, 4) with K swept once over the whole grid upward and
    once downward, after starting from the spec's initial pulse at the grid K nearest
    ``start_k`` (as a closed loop does).

    Returns ``O_up``, ``O_down`` (n_k,) in grid order and, for :func:`refine_path`, the
    fields ``u_up``, ``v_up`` (n_k, n) of the upward sweep.
    """
    n_k = k_grid.size
    start = int(np.abs(k_grid - start_k).argmin())
    run = follow_path(k_grid, angles, round_trip_orders(n_k, start), cavity_cfg, cap=cap,
                      chunk=chunk)
    down = slice(n_k - start - 1, 2 * n_k - start - 1)  # lane 0: from the end down to 0
    up = slice(start, start + n_k)                      # lane 1: from 0 up to the end
    return {'O_up': run['O'][1, up], 'O_down': run['O'][0, down][::-1],
            'u_up': run['u'][1, up], 'v_up': run['v'][1, up]}
