"""Baseline angle tables from the sweep: the fixed best angle set and a branch-continuous
tracking path for the oracle.

The point-wise envelope (:mod:`dlmpc_ros.learning.oracle`) holds, per K, the angles of the
best steady state found anywhere. The laser is multistable and those states lie on
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
- :func:`continuation_check`: the steady O along a table by continuation, K going up and
  down, from the spec's initial pulse at one K: a table keeps its branch when these match
  the table's O.

``dlmpc-train baselines`` (:func:`train_baselines_stage`) writes the tables to
``models/oracle.npz`` (no pickled objects) with ``models/oracle.json``; read them with
:func:`load_baselines`. Angles are in radians, every element pi-periodic.
"""

from __future__ import annotations

import json
import time
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.learning.sweep import wrap_angles

#: Arrays every baselines file holds (others may be added).
REQUIRED_KEYS = ('K', 'O_star', 'angles', 'tracking_angles', 'tracking_O', 'fixed_best_angles',
                 'fixed_best_worst_O', 'fixed_best_mean_O')
SCHEMA_VERSION = 1


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
    """Arrange the sweep's points (arrays of :data:`dlmpc_ros.learning.sweep.FIELDS`) by
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


def angle_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between angle sets (..., 4), each element modulo pi [rad]."""
    return np.linalg.norm(wrap_angles(np.asarray(a, float) - np.asarray(b, float)), axis=-1)


def unwrap_table(angles: np.ndarray) -> np.ndarray:
    """A table of angles (n, 4) made continuous along its first axis: every row replaced
    by its pi-equivalent nearest to the row before."""
    angles = np.asarray(angles, float)
    steps = wrap_angles(np.diff(angles, axis=0))
    return np.concatenate([angles[:1], angles[:1] + np.cumsum(steps, axis=0)])


def interpolate_angles(k_grid: np.ndarray, angles: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Angles (..., 4) at ``k`` (...,), linear in K between grid points along the
    pi-equivalents nearest to each other; constant beyond the grid's ends."""
    table = unwrap_table(angles)
    k = np.asarray(k, float)
    out = np.stack([np.interp(k, k_grid, table[:, j]) for j in range(4)], axis=-1)
    return wrap_angles(out)


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
class TrackingConfig:
    """Settings of the tracking path's dynamic program.

    Attributes
    ----------
    candidates
        Converged sweep states considered per K (the highest O first).
    jump_penalty
        Cost per radian of angle change between neighbouring K, in units of O.
    switch_penalty
        Fixed cost of changing chain (beyond the angle change), in units of O.
    max_jump
        Largest angle change of a change of chain between neighbouring K [rad]
        (pi-periodic Euclidean norm).
    break_penalty
        Cost of a transition that breaks the rules above, in units of O; such breaks are
        taken only where no allowed transition exists (a sparse sweep) and are counted.
    """

    candidates: int = 40
    jump_penalty: float = 0.05
    switch_penalty: float = 0.002
    max_jump: float = 0.3
    break_penalty: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)


def transition_cost(grid: SweepGrid, before: np.ndarray, now: np.ndarray, i: int,
                    cfg: TrackingConfig) -> tuple[np.ndarray, np.ndarray]:
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


def tracking_path(sweep: dict[str, np.ndarray], cfg: TrackingConfig | None = None) -> dict:
    """The branch-continuous path through the sweep's converged states over the K grid.

    Returns a dict with ``K`` (n_k,), ``angles`` (n_k, 4) [rad], ``O`` (n_k,) the sweep's
    steady O along the path, ``chain`` (n_k,) the sweep chain of every point, ``jump``
    (n_k - 1,) the angle change between neighbouring points [rad] and ``breaks`` the
    number of transitions that break the continuity rules (0 on a dense sweep).
    """
    cfg = cfg or TrackingConfig()
    grid = sweep_grid(sweep)
    n_k = grid.k_grid.size
    cands = []
    for i in range(n_k):
        rows = np.flatnonzero(grid.good[:, i])
        if rows.size == 0:
            raise ValueError(f'no converged sweep point at K = {grid.k_grid[i]:.4g}')
        cands.append(rows[np.argsort(grid.O[rows, i], kind='stable')[::-1][:cfg.candidates]])
    score = grid.O[cands[0], 0].copy()  # best total ending at each candidate
    back, ok = [], []
    for i in range(1, n_k):
        cost, allowed = transition_cost(grid, cands[i - 1], cands[i], i - 1, cfg)
        total = score[:, None] - cost  # (before, now)
        j = total.argmax(axis=0)
        back.append(j)
        ok.append(allowed[j, np.arange(j.size)])
        score = grid.O[cands[i], i] + total.max(axis=0)
    pick = [int(np.argmax(score))]
    breaks = 0
    for i in range(n_k - 1, 0, -1):
        breaks += int(not ok[i - 1][pick[-1]])
        pick.append(int(back[i - 1][pick[-1]]))
    pick.reverse()
    rows = np.array([cands[i][p] for i, p in enumerate(pick)])
    angles = grid.angles[rows]
    return {'K': grid.k_grid.copy(), 'angles': angles, 'O': grid.O[rows, np.arange(n_k)],
            'chain': grid.chains[rows], 'jump': angle_distance(angles[1:], angles[:-1]),
            'breaks': breaks}


# -- simulation along a table -----------------------------------------------------------------

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


@dataclass(frozen=True)
class RefineConfig:
    """Settings of the compass search along the tracking path (angles in radians).

    Attributes
    ----------
    first_step, min_step
        First and smallest compass step; a step is halved when no neighbour is better.
    max_iterations
        Compass iterations (all K points move at once, batched).
    cap, chunk
        Round-trip cap of one steady-state run, and round trips between checks.
    tolerance
        Largest relative difference between the refined O and the O found by
        continuation (either direction) for a refined point to be kept; other points go
        back to the unrefined path.
    """

    first_step: float = 0.04
    min_step: float = 0.005
    max_iterations: int = 30
    cap: int = 150
    chunk: int = 5
    tolerance: float = 1e-3

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
    best_o, best_u, best_v = start['O_up'].copy(), start['u_up'].copy(), start['v_up'].copy()
    best_a = np.asarray(angles, float).copy()
    step = np.full(n_k, cfg.first_step)
    directions = np.concatenate([np.eye(4), -np.eye(4)])  # (8, 4)
    lanes = np.arange(n_k)
    iterations = 0
    while (step >= cfg.min_step).any() and iterations < cfg.max_iterations:
        iterations += 1
        trial = best_a[:, None, :] + step[:, None, None] * directions  # (n_k, 8, 4)
        cavity = Cavity(cavity_cfg, batch=8 * n_k, angles=trial.reshape(-1, 4),
                        birefringence=np.repeat(k_grid, 8))
        cavity.set_fields(np.repeat(best_u, 8, axis=0), np.repeat(best_v, 8, axis=0))
        result = run_to_steady(cavity, cfg.cap, cfg.chunk)
        score = np.where(result.converged & result.finite, result.O, -np.inf).reshape(n_k, 8)
        u, v = cavity.fields()
        j = score.argmax(axis=1)
        better = (score[lanes, j] > best_o + 1e-7) & (step >= cfg.min_step)
        rows = lanes * 8 + j
        best_a[better] = trial[better, j[better]]
        best_o[better] = score[better, j[better]]
        best_u[better], best_v[better] = u[rows][better], v[rows][better]
        step[~better] /= 2
        if progress is not None:
            progress(iterations, float(best_o.mean()), int((step >= cfg.min_step).sum()))
    best_a = wrap_angles(best_a)
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


# -- closed-loop check ------------------------------------------------------------------------

#: The drift scenarios of the closed-loop check: name -> (scenario, parameters).
CHECK_SCENARIOS: dict[str, tuple[str, dict]] = {
    'sinusoidal': ('sinusoidal', {'amplitude': 0.25, 'period': 10000.0}),
    'random_walk_11': ('random_walk', {'sigma': 0.1, 'correlation_time': 2000.0, 'seed': 11}),
    'random_walk_12': ('random_walk', {'sigma': 0.1, 'correlation_time': 2000.0, 'seed': 12}),
    'chirp': ('chirp', {}),
    'steps': ('steps', {'times': [5000.0, 10000.0, 15000.0], 'values': [0.2, -0.2, 0.1]}),
}


def closed_loop_check(tables: dict[str, np.ndarray], envelope: dict[str, np.ndarray],
                      scenarios: dict[str, tuple[str, dict]] | None = None,
                      round_trips: int = 20000, initial_seed: int = 1,
                      cavity_cfg: CavityConfig | None = None,
                      progress: Callable[[str], None] | None = None) -> dict:
    """Closed-loop runs of table controllers against the envelope O*(K).

    ``tables`` maps a name to angles: (4,) runs a fixed-angle controller, (n_k, 4) an
    oracle controller over ``envelope['K']`` (true K to the nearest grid point's angles).
    Every run starts from :func:`random_initial_angles` of ``initial_seed``.
    Returns ``{scenario: {name: {oracle_ratio, locked_fraction, acquisition_round_trips}}}``.
    """
    from dlmpc_ros.control.baselines import FixedBestController, OracleController
    from dlmpc_ros.core.drift import make_scenario
    from dlmpc_ros.evaluation.closed_loop import random_initial_angles, run_closed_loop
    from dlmpc_ros.evaluation.metrics import run_metrics

    out: dict[str, dict] = {}
    for label, (kind, params) in (scenarios or CHECK_SCENARIOS).items():
        out[label] = {}
        for name, table in tables.items():
            table = np.asarray(table, float)
            controller = (FixedBestController(table) if table.ndim == 1
                          else OracleController(envelope['K'], table))
            record = run_closed_loop(controller, make_scenario(kind, **params), round_trips,
                                     initial_angles=random_initial_angles(initial_seed),
                                     cavity_config=cavity_cfg)
            m = run_metrics(record, envelope)
            out[label][name] = {key: m[key] for key in (
                'oracle_ratio', 'locked_fraction', 'acquisition_round_trips')}
            if progress is not None:
                progress(f'{label} {name}: O/O* {m["oracle_ratio"]:.3f}')
    return out


# -- files ------------------------------------------------------------------------------------

def save_baselines(path: Path, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write ``arrays`` to ``path`` (.npz, plain arrays only) and ``meta`` beside it
    (.json)."""
    path = Path(path)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise ValueError(f'baselines lack {missing}')
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + '.tmp.npz')
    np.savez(tmp, **{k: np.asarray(v) for k, v in arrays.items()})
    tmp.replace(path)
    path.with_suffix('.json').write_text(json.dumps(meta, indent=2, default=float))
    return path


def read_npz(path: Path, what: str, hint: str) -> dict[str, np.ndarray]:
    """Every array of a plain .npz file (no pickles are loaded).

    Raises FileNotFoundError when it is missing and ValueError when it cannot be read; both
    name ``what`` the file is and end with ``hint`` (how to make it)."""
    path = Path(path)
    if not path.is_file():
        verb = 'are' if what.endswith('s') else 'is'
        raise FileNotFoundError(f'{what} {path} {verb} missing; {hint}')
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise ValueError(f'{what} {path} cannot be read ({err}); {hint}') from None


def load_baselines(path: Path) -> dict[str, np.ndarray]:
    """The baseline tables of ``path`` (models/oracle.npz) as a dict of arrays.

    Raises FileNotFoundError when the file is missing and ValueError when it cannot be
    read or lacks one of :data:`REQUIRED_KEYS`; both say to run ``dlmpc-train baselines``.
    """
    path = Path(path)
    hint = 'run `dlmpc-train baselines` to make it'
    arrays = read_npz(path, 'baseline tables', hint)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise ValueError(f'baseline tables {path} lack {missing} (an older or foreign file); '
                         f'{hint}')
    return arrays


# -- the training stage -----------------------------------------------------------------------

def build_baselines(sweep: dict[str, np.ndarray], envelope: dict[str, np.ndarray],
                    cavity_cfg: CavityConfig | None = None,
                    tracking_cfg: TrackingConfig | None = None,
                    refine_cfg: RefineConfig | None = None,
                    progress: Callable[[str], None] | None = None) -> dict[str, np.ndarray]:
    """All baseline tables over the envelope's K grid (see :func:`train_baselines_stage`)."""
    say = progress or (lambda text: None)
    k_grid = envelope['K']
    fixed = fixed_best_angles(sweep)
    path = tracking_path(sweep, tracking_cfg)
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
        'K': k_grid, 'O_star': envelope['O_star'], 'angles': envelope['angles'],
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


def summarize(arrays: dict[str, np.ndarray]) -> dict:
    """JSON-ready figures of the tables (for metrics.json and oracle.json)."""
    o_star = arrays['O_star']
    mean_star = float(o_star.mean())
    jumps = angle_distance(arrays['angles'][1:], arrays['angles'][:-1])
    track_jumps = angle_distance(arrays['tracking_angles'][1:], arrays['tracking_angles'][:-1])
    chain = arrays['tracking_chain']
    out = {
        'mean_O_star': mean_star,
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


def train_baselines_stage(paths, quick: bool = False, cavity_cfg: CavityConfig | None = None,
                          show_progress: bool = True) -> dict:
    """``dlmpc-train baselines``: build the tables from ``data/sweep`` and
    ``data/oracle.npz``, run the closed-loop check, write ``models/oracle.npz`` and
    ``models/oracle.json``; returns the stage's metrics.

    ``paths`` is a :class:`dlmpc_ros.learning.pipeline.Paths`. ``quick`` (tests) skips the
    refinement and checks one scenario for 1,000 round trips.
    """
    from dlmpc_ros.learning import shards
    from dlmpc_ros.learning.oracle import load_envelope

    started = time.monotonic()

    def say(text: str) -> None:
        if show_progress:
            print(f'baselines: {text}', flush=True)

    envelope = load_envelope(paths.oracle)
    sweep = shards.load_dataset(paths.sweep)
    tracking_cfg = TrackingConfig()
    refine_cfg = None if quick else RefineConfig()
    arrays = build_baselines(sweep, envelope, cavity_cfg, tracking_cfg, refine_cfg, say)
    summary = summarize(arrays)
    tables = {'oracle_pointwise': arrays['angles'], 'oracle_tracking': arrays['tracking_angles'],
              'fixed_best': arrays['fixed_best_angles']}
    if 'tracking_refined_angles' in arrays:
        tables['oracle_tracking_refined'] = arrays['tracking_refined_angles']
    scenarios = dict(list(CHECK_SCENARIOS.items())[:1]) if quick else CHECK_SCENARIOS
    round_trips = 1000 if quick else 20000
    check = closed_loop_check(tables, envelope, scenarios, round_trips, 1, cavity_cfg, say)
    meta = {
        'schema_version': SCHEMA_VERSION,
        'made_by': 'dlmpc-train baselines (dlmpc_ros.learning.baselines)',
        'how': ('fixed_best: the sweep chain with the highest worst-case steady O over K '
                '(non-converged = 0). tracking: dynamic program over the K grid through the '
                'top sweep states per K, maximizing sum O - jump_penalty * angle change - '
                'switch_penalty per change of chain; a change of chain only between states '
                'converged at both K with equal pulse counts and angles within max_jump. '
                'tracking_refined: per-K compass search on the steady O warm-started from '
                'the path\'s continuation state, kept where continuation up and down '
                'reproduces it. angles / O_star: copied from the oracle envelope.'),
        'sweep_fingerprint': shards.metadata(paths.sweep).get('fingerprint'),
        'oracle_envelope': str(paths.oracle),
        'tracking_settings': tracking_cfg.to_dict(),
        'refine_settings': None if refine_cfg is None else refine_cfg.to_dict(),
        'closed_loop_check': {'round_trips': round_trips, 'initial_angles_seed': 1,
                              'scenarios': dict(scenarios)},
        'quick': quick,
    }
    metrics = {**summary, 'closed_loop': check, 'quick': quick,
               'wall_seconds': round(time.monotonic() - started, 1)}
    meta.update({'summary': summary, 'closed_loop': check,
                 'wall_seconds': metrics['wall_seconds']})
    save_baselines(paths.models_dir / 'oracle.npz', arrays, meta)
    return metrics
