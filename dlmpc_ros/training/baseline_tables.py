"""Baseline angle tables from the sweep: the fixed best angle set and a branch-continuous
tracking path for the oracle.

The point-wise envelope (:mod:`dlmpc_ros.training.envelope`) holds, per K, the angles of
the best steady state found anywhere. The laser is multistable and those states lie on
different branches (found from the spec's initial pulse or by continuation in K): an
oracle that jumps between them as K drifts drops the pulse, and the simulated laser has
no noise to start a new one. The tables here keep the laser on one branch:

- :func:`fixed_best_angles`: the one angle set whose worst steady O over the whole K
  range is highest (a non-converged or blown-up point counts as O = 0);
- :func:`tracking_path`: per K grid point, the angles of a converged sweep state, chosen
  by a dynamic program over the K grid that maximizes the summed O minus a penalty on the
  angle change between neighbouring K (pi-periodic distance). The sweep's chains are
  continuation branches, so staying on one chain costs nothing; a change of chain is
  allowed only between nearby angle sets whose states have the same pulse count and are
  both converged at both K points;
- :func:`refine_path`: the path's angles moved, per K, uphill on the steady O by a compass
  search warm-started from the path's own state (so it stays on the branch);
- :func:`~dlmpc_ros.training.continuation.continuation_check` checks each table: the
  steady O along it by continuation, K going up and down, from the spec's initial pulse
  at one K; a table keeps its branch when these match the table's O.

:func:`build_baselines` makes them all; ``dlmpc-train baselines``
(:mod:`dlmpc_ros.training.stages.baselines`) writes them to ``models/oracle.npz``
(:mod:`dlmpc_ros.learning.tables`). Angles are in radians, every element pi-periodic.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import angle_distance, wrap_angles
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.learning.tables import SCHEMA_VERSION
from dlmpc_ros.training.continuation import continuation_check
from dlmpc_ros.training.envelope import check_symmetric, mirrored
from dlmpc_ros.training.search import best_path, compass_search


# -- the sweep as a table ---------------------------------------------------------------------

@dataclass(frozen=True)
class SweepGrid:
    """The sweep as a (chain, K) table.

    Attributes
    ----------
    chains
        Chain ids (n_chain,).
    k_grid
        K values (n_k,).
    angles
        Angle set of every chain (n_chain, 4) [rad].
    O
        Steady O (n_chain, n_k); 0 where the point did not converge or blew up.
    good
        Converged and finite (n_chain, n_k).
    pulses
        Pulse count (n_chain, n_k); -1 where the sweep has no point.
    """

    chains: np.ndarray
    k_grid: np.ndarray
    angles: np.ndarray
    O: np.ndarray  # noqa: E741
    good: np.ndarray
    pulses: np.ndarray


def sweep_grid(sweep: dict[str, np.ndarray]) -> SweepGrid:
    """Arrange the sweep's points (arrays of :data:`dlmpc_ros.training.sweep.FIELDS`) by
    chain and K."""
    chains = np.unique(sweep['chain'])
    k_grid = np.unique(sweep['K'])
    row = np.searchsorted(chains, sweep['chain'])
    col = np.searchsorted(k_grid, sweep['K'])
    good = sweep['converged'] & sweep['finite']
    shape = (chains.size, k_grid.size)
    o = np.zeros(shape)
    o[row, col] = np.where(good, np.nan_to_num(sweep['O']), 0.0)
    good_grid = np.zeros(shape, bool)
    good_grid[row, col] = good
    pulses = np.full(shape, -1, np.int64)
    pulses[row, col] = sweep['pulses']
    angles = np.zeros((chains.size, 4))
    angles[row] = sweep['alpha']
    return SweepGrid(chains, k_grid, angles, o, good_grid, pulses)


# -- fixed best -------------------------------------------------------------------------------

def fixed_best_angles(sweep: dict[str, np.ndarray]) -> dict:
    """The sweep's angle set with the highest worst-case steady O over the K grid.

    Returns a dict with ``angles`` (4,) [rad], ``worst_O`` and ``mean_O`` (over the K
    grid, non-converged or blown-up points counting as 0), ``chain`` (its sweep id) and
    ``O`` (n_k,) its sweep O per K. Ties in the worst case go to the higher mean.
    """
    grid = sweep_grid(sweep)
    worst = grid.O.min(axis=1)
    mean = grid.O.mean(axis=1)
    best = int(np.lexsort((mean, worst))[-1])
    return {'angles': grid.angles[best].copy(), 'worst_O': float(worst[best]),
            'mean_O': float(mean[best]), 'chain': int(grid.chains[best]),
            'O': grid.O[best].copy()}


# -- tracking path ----------------------------------------------------------------------------

@dataclass(frozen=True)
class PathConfig:
    """Settings of the tracking path's dynamic program."""

    candidates: int = 40
    """Converged sweep states considered per K (the highest O first)."""
    jump_penalty: float = 0.05
    """Cost per radian of angle change between neighbouring K, in units of O."""
    switch_penalty: float = 0.002
    """Fixed cost of changing chain (beyond the angle change), in units of O."""
    max_jump: float = 0.3
    """Largest angle change of a change of chain between neighbouring K [rad]
    (pi-periodic Euclidean norm)."""
    break_penalty: float = 1.0
    """Cost of a transition that breaks the rules above, in units of O; such breaks are
    taken only where no allowed transition exists (a sparse sweep) and are counted."""

    def __post_init__(self) -> None:
        checks.counts(self, 'candidates')
        checks.non_negative(self, 'jump_penalty', 'switch_penalty', 'break_penalty')
        checks.positive(self, 'max_jump')

    def to_dict(self) -> dict:
        return asdict(self)


def transition_cost(grid: SweepGrid, before: np.ndarray, now: np.ndarray, i: int,
                    cfg: PathConfig) -> tuple[np.ndarray, np.ndarray]:
    """Cost and allowed mask, (len(before), len(now)) each, of going from the chain rows
    ``before`` at K index ``i`` to the chain rows ``now`` at ``i + 1``."""
    same = before[:, None] == now[None, :]
    jump = angle_distance(grid.angles[before][:, None], grid.angles[now][None, :])
    # A change of chain: both states exist at both K, with the same pulse count.
    both = (grid.good[before, i][:, None] & grid.good[before, i + 1][:, None]
            & grid.good[now, i][None, :] & grid.good[now, i + 1][None, :])
    pulses = grid.pulses[before, i + 1][:, None] == grid.pulses[now, i + 1][None, :]
    allowed = same | (both & pulses & (jump <= cfg.max_jump))
    cost = cfg.jump_penalty * jump + cfg.switch_penalty * ~same
    return np.where(allowed, cost, cost + cfg.break_penalty), allowed


def tracking_path(sweep: dict[str, np.ndarray], cfg: PathConfig | None = None) -> dict:
    """The branch-continuous path through the sweep's converged states over the K grid.

    Returns a dict with ``K`` (n_k,), ``angles`` (n_k, 4) [rad], ``O`` (n_k,) the sweep's
    steady O along the path, ``chain`` (n_k,) the sweep chain of every point, ``jump``
    (n_k - 1,) the angle change between neighbouring points [rad] and ``breaks`` the
    number of transitions that break the continuity rules (0 on a dense sweep).
    """
    cfg = cfg or PathConfig()
    grid = sweep_grid(sweep)
    n_k = grid.k_grid.size
    cands = []
    for i in range(n_k):
        rows = np.flatnonzero(grid.good[:, i])
        if rows.size == 0:
            raise ValueError(f'no converged sweep point at K = {grid.k_grid[i]:.4g}')
        cands.append(rows[np.argsort(grid.O[rows, i], kind='stable')[::-1][:cfg.candidates]])
    # (cost, allowed) of every step from K index i - 1 to i
    steps = [None] + [transition_cost(grid, cands[i - 1], cands[i], i - 1, cfg)
                      for i in range(1, n_k)]
    pick = best_path([grid.O[cands[i], i] for i in range(n_k)], lambda i: steps[i][0])
    breaks = sum(int(not steps[i][1][pick[i - 1], pick[i]]) for i in range(1, n_k))
    rows = np.array([cands[i][p] for i, p in enumerate(pick)])
    angles = grid.angles[rows]
    return {'K': grid.k_grid.copy(), 'angles': angles, 'O': grid.O[rows, np.arange(n_k)],
            'chain': grid.chains[rows], 'jump': angle_distance(angles[1:], angles[:-1]),
            'breaks': breaks}


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the compass search along the tracking path (angles in radians)."""

    first_step: float = 0.04
    """First compass step; a step is halved when no neighbour is better."""
    min_step: float = 0.005
    """Smallest compass step."""
    max_iterations: int = 30
    """Compass iterations (all K points move at once, batched)."""
    cap: int = 150
    """Round-trip cap of one steady-state run."""
    chunk: int = 5
    """Round trips between two steady-state checks."""
    tolerance: float = 1e-3
    """Largest relative difference between the refined O and the O found by continuation
    (either direction) for a refined point to be kept; other points go back to the
    unrefined path."""

    def __post_init__(self) -> None:
        checks.positive(self, 'first_step', 'min_step', 'tolerance')
        checks.counts(self, 'max_iterations', 'cap', 'chunk')

    def to_dict(self) -> dict:
        return asdict(self)


def refine_path(k_grid: np.ndarray, angles: np.ndarray, cavity_cfg: CavityConfig | None = None,
                cfg: RefineConfig | None = None,
                progress: Callable[[int, float, int], None] | None = None) -> dict:
    """Move the path's angles (n_k, 4) uphill on the steady O, per K, from the path's own
    steady state (reached by continuation), then keep only the refined points whose O
    the continuation check reproduces in both directions.

    Returns ``angles`` (n_k, 4), ``O`` (n_k,) the refined steady O, ``O_up``, ``O_down``
    (n_k,) from :func:`continuation_check` of the result, ``reverted`` (n_k,) the points
    put back to the input path, and ``iterations``.
    """
    cfg = cfg or RefineConfig()
    n_k = k_grid.size
    start = continuation_check(k_grid, angles, cavity_cfg)
    found = compass_search(angles, k_grid, start['O_up'], (start['u_up'], start['v_up']),
                           cavity_cfg, first_step=cfg.first_step, min_step=cfg.min_step,
                           max_iterations=cfg.max_iterations, cap=cfg.cap, chunk=cfg.chunk,
                           wrap=False, progress=progress)
    best_a, best_o = wrap_angles(found.angles), found.objective
    iterations = found.iterations
    reverted = np.zeros(n_k, bool)
    for attempt in range(4):  # keep the points that continuation reproduces, both ways
        check = continuation_check(k_grid, best_a, cavity_cfg)
        off = ((np.abs(check['O_up'] - best_o) > cfg.tolerance * best_o)
               | (np.abs(check['O_down'] - best_o) > cfg.tolerance * best_o)) & ~reverted
        if not off.any() or attempt == 3:
            break
        reverted |= off
        best_a[off] = angles[off]
        best_o[off] = start['O_up'][off]
    return {'angles': best_a, 'O': best_o, 'O_up': check['O_up'], 'O_down': check['O_down'],
            'reverted': reverted, 'iterations': iterations}


# -- all tables ------------------------------------------------------------------------------

def build_baselines(sweep: dict[str, np.ndarray], envelope: dict[str, np.ndarray],
                    cavity_cfg: CavityConfig | None = None,
                    path_cfg: PathConfig | None = None,
                    refine_cfg: RefineConfig | None = None,
                    progress: Callable[[str], None] | None = None) -> dict[str, np.ndarray]:
    """All baseline tables over the envelope's K grid, as the arrays of
    ``models/oracle.npz``; ``refine_cfg`` None skips the refinement."""
    say = progress or (lambda text: None)
    k_grid = envelope['K']
    fixed = fixed_best_angles(sweep)
    path = tracking_path(sweep, path_cfg)
    if path['K'].shape != k_grid.shape or not np.allclose(path['K'], k_grid):
        raise ValueError('the sweep and the oracle envelope have different K grids; run '
                         '`dlmpc-data oracle` again')
    say(f'tracking path: mean sweep O {path["O"].mean():.4f}, '
        f'{int((path["chain"][1:] != path["chain"][:-1]).sum())} changes of chain, '
        f'{path["breaks"]} breaks')
    tracking = continuation_check(k_grid, path['angles'], cavity_cfg)
    fixed_check = continuation_check(k_grid, np.broadcast_to(fixed['angles'], (k_grid.size, 4)),
                                     cavity_cfg)
    arrays = {
        **envelope_arrays(envelope),
        'tracking_angles': path['angles'], 'tracking_O': path['O'],
        'tracking_chain': path['chain'], 'tracking_breaks': np.array(path['breaks']),
        'tracking_O_up': tracking['O_up'], 'tracking_O_down': tracking['O_down'],
        'fixed_best_angles': fixed['angles'], 'fixed_best_worst_O': np.array(fixed['worst_O']),
        'fixed_best_mean_O': np.array(fixed['mean_O']), 'fixed_best_chain': np.array(
            fixed['chain']), 'fixed_best_O': fixed['O'],
        'fixed_best_O_up': fixed_check['O_up'], 'fixed_best_O_down': fixed_check['O_down'],
        'schema_version': np.array(SCHEMA_VERSION),
    }
    if refine_cfg is not None:
        def step(iteration: int, mean_o: float, active: int) -> None:
            say(f'refine: iteration {iteration:2d}  mean O {mean_o:.4f}  K points still '
                f'moving {active}')

        refined = refine_path(k_grid, path['angles'], cavity_cfg, refine_cfg, step)
        arrays.update({
            'tracking_refined_angles': refined['angles'], 'tracking_refined_O': refined['O'],
            'tracking_refined_O_up': refined['O_up'],
            'tracking_refined_O_down': refined['O_down'],
            'tracking_refined_reverted': refined['reverted']})
    return arrays


def envelope_arrays(envelope: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The envelope part of the tables: the search's envelope mirrored
    (:func:`~dlmpc_ros.training.envelope.mirrored`), checked for its symmetry; ``K``,
    ``O_star``, ``angles``, ``O_star_own`` (the search's own) and ``from_mirror``."""
    env = mirrored(envelope)
    check_symmetric(env)
    return {key: np.asarray(env[key]) for key in ('K', 'O_star', 'angles', 'O_star_own',
                                                  'from_mirror')}


def summarize(arrays: dict[str, np.ndarray]) -> dict:
    """JSON-ready figures of the tables (for metrics.json and oracle.json)."""
    o_star = arrays['O_star']
    mean_star = float(o_star.mean())
    jumps = angle_distance(arrays['angles'][1:], arrays['angles'][:-1])
    track_jumps = angle_distance(arrays['tracking_angles'][1:], arrays['tracking_angles'][:-1])
    chain = arrays['tracking_chain']
    out = {
        'mean_O_star': mean_star,
        'mirror_gain_mean': float(np.mean(o_star / arrays['O_star_own'] - 1))
        if 'O_star_own' in arrays else None,
        'points_from_mirror': int(np.sum(arrays['from_mirror'])) if 'from_mirror' in arrays
        else None,
        'pointwise_jumps_over_0.3_rad': int((jumps > 0.3).sum()),
        'pointwise_jump_K': [round(float(k), 4) for k in arrays['K'][1:][jumps > 0.3]],
        'fixed_best': {
            'angles': arrays['fixed_best_angles'].tolist(),
            'chain': int(arrays['fixed_best_chain']),
            'worst_O': float(arrays['fixed_best_worst_O']),
            'mean_O': float(arrays['fixed_best_mean_O']),
            'mean_O_over_mean_O_star': float(arrays['fixed_best_mean_O']) / mean_star,
            'continuation_min_O_up_down': float(min(arrays['fixed_best_O_up'].min(),
                                                    arrays['fixed_best_O_down'].min())),
        },
        'tracking': {
            'mean_O': float(arrays['tracking_O'].mean()),
            'min_O': float(arrays['tracking_O'].min()),
            'mean_O_over_mean_O_star': float(arrays['tracking_O'].mean()) / mean_star,
            'changes_of_chain': int((chain[1:] != chain[:-1]).sum()),
            'largest_jump_rad': float(track_jumps.max()),
            'breaks': int(arrays['tracking_breaks']),
            'continuation_max_abs_error_up': float(np.abs(
                arrays['tracking_O_up'] - arrays['tracking_O']).max()),
            'continuation_max_abs_error_down': float(np.abs(
                arrays['tracking_O_down'] - arrays['tracking_O']).max()),
        },
    }
    if 'tracking_refined_angles' in arrays:
        refined = arrays['tracking_refined_O']
        out['tracking_refined'] = {
            'mean_O': float(refined.mean()), 'min_O': float(refined.min()),
            'mean_O_over_mean_O_star': float(refined.mean()) / mean_star,
            'largest_jump_rad': float(angle_distance(arrays['tracking_refined_angles'][1:],
                                                     arrays['tracking_refined_angles'][:-1]
                                                     ).max()),
            'largest_move_from_path_rad': float(angle_distance(
                arrays['tracking_refined_angles'], arrays['tracking_angles']).max()),
            'reverted_points': int(arrays['tracking_refined_reverted'].sum()),
            'continuation_max_abs_error_up': float(np.abs(
                arrays['tracking_refined_O_up'] - refined).max()),
            'continuation_max_abs_error_down': float(np.abs(
                arrays['tracking_refined_O_down'] - refined).max()),
        }
    return out


