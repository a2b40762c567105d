"""The oracle envelope O*(K): the best steady-state objective and its angles per K.

Per K of the sweep's grid, the best steady states of the sweep are re-run from the spec's
initial pulse, and the best of them is refined by the batched compass search of
:mod:`dlmpc_ros.training.search` (angles kept in [-pi/2, pi/2)). The envelope keeps, per
K, the better of the refined optimum and the sweep's best point (which may lie on a
branch reached only by continuation in K). It is written to ``data/oracle.npz``
(:mod:`dlmpc_ros.learning.tables` reads it); the data's exploring policy steers near
its angles.

The yardstick of the evaluation is :func:`mirrored`: at each K the better of the search
there and the mirror of the search at -K (:mod:`dlmpc_ros.core.symmetry`), symmetric in
K. ``dlmpc-train baselines`` writes it into ``models/oracle.npz``.

A plant (:mod:`dlmpc_ros.core.plants`) has its own envelope, :func:`plant_envelope`:
searched on fewer K points from the nominal tables' angles and their mirrors, in minutes
instead of the sweep's quarter of an hour, and cached by the plant's fingerprint
(:func:`cached_plant_envelope`). :func:`draw_plant` draws a family's plants, redrawing
one that does not mode-lock at every K.

That search starts every K from the nominal tables alone, so it can miss a plant's optimum
where the plant's best branch lies away from the nominal angles (family-2 lost up to 15 %
at |K| >= 0.15). :func:`continue_envelope` adds a continuation layer in K on top of it:
each K tries the final angles of its neighbouring K points and the mirrors of those at -K
(from the spec's pulse and warm from their fields), refines a start that beats O*(K) by
the compass search, and sweeps until no K point moves; it only raises O*(K) and keeps it
symmetric. :func:`cached_plant_envelope`, which every caller uses, returns the continued
envelope, cached apart from the base (:class:`ContinuationConfig` names its key), so
the base envelopes already cached stay valid.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import angle_distance, wrap_angles
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import BIREFRINGENCE_RANGE, CavityConfig
from dlmpc_ros.core.plants import (NOMINAL, PHYSICS_FIELDS, PlantFamily, plant_fingerprint,
                                   plant_parameters)
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.core.symmetry import mirror_angles, mirror_fields
from dlmpc_ros.learning.tables import read_npz, write_npz
from dlmpc_ros.scaleout import TaskFailure, run_tasks
from dlmpc_ros.training import shards
from dlmpc_ros.training.search import MIN_GAIN, compass_search, steady_scores


@dataclass(frozen=True)
class OracleConfig:
    """Settings of the envelope search (angles in radians)."""

    candidates: int = 4
    """Best sweep points per K re-run from the initial pulse; the best starts the search."""
    first_step: float = 0.08
    """First compass step [rad]."""
    min_step: float = 0.005
    """Smallest compass step [rad]: a K point whose step halves below it stops."""
    max_iterations: int = 40
    """Compass iterations (all K points at once)."""
    cap: int = 300
    """Round-trip cap of one steady-state run."""
    chunk: int = 5
    """Round trips between two steady-state checks."""
    check_directions: int = 16
    """Random directions probed at twice ``min_step`` around the result (how close to a
    local maximum it is)."""
    seed: int = 0
    """Seed of the probe directions."""

    def __post_init__(self) -> None:
        checks.counts(self, 'candidates', 'max_iterations', 'cap', 'chunk',
                      'check_directions')
        checks.positive(self, 'first_step', 'min_step')
        checks.counts(self, 'seed', minimum=0)

    def to_dict(self) -> dict:
        return asdict(self)


def refine_envelope(sweep: dict[str, np.ndarray], cavity_cfg: CavityConfig,
                    cfg: OracleConfig, progress=None,
                    k_indices: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Compute the envelope from sweep data; returns arrays over the K grid (or over the
    grid points ``k_indices``). The K points are searched together: each steady-state
    batch runs until its last laser finishes, and the fields that warm-start the next
    step are those at that end, so a split of the grid gives a slightly different
    envelope (``dlmpc-data oracle`` runs the whole grid as one task)."""
    k_all = np.unique(sweep['K'])
    k_indices = np.arange(k_all.size) if k_indices is None else np.asarray(k_indices, int)
    k_grid = k_all[k_indices]
    n_k = k_grid.size
    good = sweep['converged'] & sweep['finite']
    # Candidates: the best converged sweep points at each K.
    cand_angles = np.zeros((n_k, cfg.candidates, 4))
    sweep_best_o = np.full(n_k, -np.inf)
    sweep_best_angles = np.zeros((n_k, 4))
    for i, k in enumerate(k_grid):
        rows = np.flatnonzero(good & (sweep['K'] == k))
        order = rows[np.argsort(sweep['O'][rows])[::-1]]
        if order.size == 0:
            raise ValueError(f'no converged sweep point at K = {k}')
        sweep_best_o[i] = sweep['O'][order[0]]
        sweep_best_angles[i] = sweep['alpha'][order[0]]
        picks = order[:cfg.candidates]
        cand_angles[i] = sweep['alpha'][np.resize(picks, cfg.candidates)]
    # Re-run the candidates from the initial pulse; keep the best per K.
    flat_k = np.repeat(k_grid, cfg.candidates)
    score, (u, v) = steady_scores(cavity_cfg, cand_angles.reshape(-1, 4), flat_k, cap=cfg.cap,
                                  chunk=cfg.chunk)
    score = score.reshape(n_k, cfg.candidates)
    pick = np.argmax(score, axis=1)
    rows = np.arange(n_k) * cfg.candidates + pick
    start_o = score[np.arange(n_k), pick].copy()
    found = compass_search(cand_angles[np.arange(n_k), pick], k_grid, start_o,
                           (u[rows], v[rows]), cavity_cfg, first_step=cfg.first_step,
                           min_step=cfg.min_step, max_iterations=cfg.max_iterations,
                           cap=cfg.cap, chunk=cfg.chunk, wrap=True, progress=progress)
    best_angles, best_o = found.angles, found.objective
    # How close to a local maximum: random directions at twice the final step.
    rng = np.random.default_rng(cfg.seed)
    dirs = rng.standard_normal((k_all.size, cfg.check_directions, 4))[k_indices]
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    probe = wrap_angles(best_angles[:, None, :] + 2 * cfg.min_step * dirs)
    score, _ = steady_scores(cavity_cfg, probe.reshape(-1, 4),
                             np.repeat(k_grid, cfg.check_directions),
                             (np.repeat(found.u, cfg.check_directions, axis=0),
                              np.repeat(found.v, cfg.check_directions, axis=0)),
                             cfg.cap, cfg.chunk)
    probe_gain = score.reshape(n_k, cfg.check_directions).max(axis=1) / best_o - 1
    use_sweep = sweep_best_o > best_o
    return {
        'K': k_grid,
        'O_star': np.where(use_sweep, sweep_best_o, best_o),
        'angles': np.where(use_sweep[:, None], sweep_best_angles, best_angles),
        'from_sweep': use_sweep,
        'refined_O': best_o, 'refined_angles': best_angles, 'start_O': start_o,
        'sweep_best_O': sweep_best_o, 'probe_gain': probe_gain,
        'iterations': np.array(found.iterations),
    }


@dataclass(frozen=True)
class EnvelopeTask:
    """The envelope of a sweep, searched by a worker."""

    sweep_dir: str
    cavity: CavityConfig
    cfg: OracleConfig


def envelope_of_sweep(task: EnvelopeTask) -> dict[str, np.ndarray]:
    """:func:`refine_envelope` of the task's sweep."""
    return refine_envelope(shards.load_dataset(task.sweep_dir), task.cavity, task.cfg)


def generate_oracle(sweep_dir: Path, out_path: Path, cavity_cfg: CavityConfig,
                    cfg: OracleConfig, show_progress: bool = True, workers: int = 1,
                    scheduler: str | None = None) -> dict:
    """``dlmpc-data oracle``: the envelope of the sweep in ``sweep_dir``, written to
    ``out_path`` with a .json note; returns the note. With workers or a scheduler it runs
    as one task on Dask (the grid is not split: see :func:`refine_envelope`)."""
    started = time.monotonic()
    sweep = shards.load_dataset(sweep_dir)

    def progress(iteration, mean_o, active):
        if show_progress:
            print(f'oracle: iteration {iteration:2d}  mean O* {mean_o:.4f}  K points still '
                  f'moving {active}', flush=True)

    if workers == 1 and scheduler is None:
        env = refine_envelope(sweep, cavity_cfg, cfg, progress)
    else:
        env, = run_tasks(envelope_of_sweep, [EnvelopeTask(str(sweep_dir), cavity_cfg, cfg)],
                         workers, scheduler, desc='envelope', show_progress=show_progress)
        if isinstance(env, TaskFailure):
            raise RuntimeError(str(env))
    meta = {
        'settings': cfg.to_dict(), 'sweep_fingerprint': shards.metadata(sweep_dir).get(
            'fingerprint'), 'wall_seconds': round(time.monotonic() - started, 1),
        'k_points': int(env['K'].size), 'mean_O_star': float(env['O_star'].mean()),
        'mean_gain_over_sweep_best': float(np.mean(env['O_star'] / env['sweep_best_O'] - 1)),
        'points_taken_from_sweep': int(env['from_sweep'].sum()),
        'max_gain_of_random_probes_at_2x_min_step': float(env['probe_gain'].max()),
    }
    write_npz(out_path, env, meta)
    return meta


# -- the mirror ---------------------------------------------------------------------------------

def mirrored(envelope: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The envelope with each K's best taken over its own search and the mirror of the
    search at -K (:mod:`dlmpc_ros.core.symmetry`): ``O_star`` becomes symmetric in K and
    ``from_mirror`` (n_k,) marks the points whose angles are a mirrored twin's. The K grid
    must be symmetric about 0."""
    k = np.asarray(envelope['K'], float)
    if not np.allclose(k, -k[::-1], atol=1e-12):
        raise ValueError('the mirror needs a K grid symmetric about 0')
    own, twin = np.asarray(envelope['O_star'], float), np.asarray(envelope['O_star'])[::-1]
    use = twin > own
    angles = np.where(use[:, None], wrap_angles(mirror_angles(envelope['angles'][::-1])),
                      envelope['angles'])
    return {**envelope, 'O_star': np.maximum(own, twin), 'angles': angles,
            'O_star_own': own, 'from_mirror': use}


def check_symmetric(envelope: dict[str, np.ndarray], rtol: float = 1e-12) -> None:
    """ValueError unless O*(K) = O*(-K), as the mirror makes it."""
    o = np.asarray(envelope['O_star'], float)
    if not np.allclose(o, o[::-1], rtol=rtol, atol=0):
        raise ValueError(f'O*(K) is not symmetric: largest relative gap '
                         f'{np.max(np.abs(o - o[::-1]) / o):.3g}')


# -- a plant's envelope --------------------------------------------------------------------------

@dataclass(frozen=True)
class PlantEnvelopeConfig:
    """Settings of a plant's envelope, searched from the nominal tables (angles in rad)."""

    k_points: int = 21
    """K grid points over [-0.3, 0.3] (odd, so that the grid holds K = 0)."""
    neighbours: int = 3
    """Rows of each nominal table nearest each K (and their mirrors) tried from cold."""
    first_step: float = 0.04
    """First compass step (the seeds start near an optimum of a cavity like this one)."""
    min_step: float = 0.005
    """Smallest compass step."""
    max_iterations: int = 30
    """Compass iterations."""
    cap: int = 150
    """Round-trip cap of one steady-state run (of a cold start: twice this)."""
    chunk: int = 5
    """Round trips between two steady-state checks."""

    def __post_init__(self) -> None:
        checks.counts(self, 'k_points', minimum=3)
        if self.k_points % 2 == 0:
            raise ValueError('PlantEnvelopeConfig.k_points must be odd (the grid holds 0)')
        checks.counts(self, 'neighbours', 'max_iterations', 'cap', 'chunk')
        checks.positive(self, 'first_step', 'min_step')

    def k_grid(self) -> np.ndarray:
        return np.linspace(*BIREFRINGENCE_RANGE, self.k_points)

    def to_dict(self) -> dict:
        return asdict(self)


#: The nominal tables whose rows seed a plant's search (those a baselines file has).
SEED_TABLES = ('angles', 'tracking_angles', 'tracking_refined_angles')


def seed_candidates(tables: dict[str, np.ndarray], k_grid: np.ndarray,
                    neighbours: int) -> np.ndarray:
    """(n_k, n_cand, 4) angle sets to try at each K: the rows of the nominal tables
    nearest to K and, mirrored, the rows nearest to -K."""
    nominal_k = np.asarray(tables['K'], float)
    out = []
    for k in k_grid:
        rows = []
        for key in SEED_TABLES:
            if key not in tables:
                continue
            own = np.argsort(np.abs(nominal_k - k), kind='stable')[:neighbours]
            twin = np.argsort(np.abs(nominal_k + k), kind='stable')[:neighbours]
            rows += [tables[key][own], wrap_angles(mirror_angles(tables[key][twin]))]
        out.append(np.concatenate(rows))
    return np.stack(out)


def plant_candidates(cavity_cfg: CavityConfig, tables: dict[str, np.ndarray],
                     cfg: PlantEnvelopeConfig) -> dict[str, np.ndarray]:
    """Every seed candidate run from the spec's pulse at every K of the grid: ``K``
    (n_k,), ``angles`` (n_k, n_cand, 4), ``O`` (n_k, n_cand) (-inf: not converged),
    ``pulses`` (n_k, n_cand) and the fields ``u``, ``v`` (n_k, n_cand, n)."""
    k_grid = cfg.k_grid()
    cand = seed_candidates(tables, k_grid, cfg.neighbours)
    n_k, n_c = cand.shape[:2]
    cavity = Cavity(cavity_cfg, batch=n_k * n_c, angles=cand.reshape(-1, 4),
                    birefringence=np.repeat(k_grid, n_c))
    result = run_to_steady(cavity, 2 * cfg.cap, cfg.chunk)
    score = np.where(result.converged & result.finite, result.O, -np.inf)
    u, v = cavity.fields()
    return {'K': k_grid, 'angles': cand, 'O': score.reshape(n_k, n_c),
            'pulses': result.pulses.reshape(n_k, n_c),
            'u': u.reshape(n_k, n_c, -1), 'v': v.reshape(n_k, n_c, -1)}


def mode_locks(candidates: dict[str, np.ndarray]) -> bool:
    """Whether some candidate holds a converged pulse (>= 1 pulse) at every K."""
    locked = np.isfinite(candidates['O']) & (candidates['pulses'] >= 1)
    return bool(locked.any(axis=1).all())


def plant_envelope(cavity_cfg: CavityConfig, tables: dict[str, np.ndarray],
                   cfg: PlantEnvelopeConfig | None = None, progress=None
                   ) -> dict[str, np.ndarray]:
    """The envelope O*(K) of a plant: the nominal tables' nearby rows and their mirrors
    tried from the spec's pulse, the best at each K refined by the compass search, then
    :func:`mirrored`. Returns ``K``, ``O_star``, ``angles`` and the search's figures."""
    cfg = cfg or PlantEnvelopeConfig()
    cand = plant_candidates(cavity_cfg, tables, cfg)
    n_k = cand['K'].size
    lanes = np.arange(n_k)
    pick = np.argmax(cand['O'], axis=1)
    start_o = cand['O'][lanes, pick]
    found = compass_search(cand['angles'][lanes, pick], cand['K'], start_o,
                           (cand['u'][lanes, pick], cand['v'][lanes, pick]), cavity_cfg,
                           first_step=cfg.first_step, min_step=cfg.min_step,
                           max_iterations=cfg.max_iterations, cap=cfg.cap, chunk=cfg.chunk,
                           wrap=True, progress=progress)
    envelope = mirrored({'K': cand['K'], 'O_star': found.objective, 'angles': found.angles})
    envelope.update({'start_O': start_o, 'iterations': np.array(found.iterations),
                     'mode_locks': np.array(mode_locks(cand))})
    check_symmetric(envelope)
    return envelope


# -- continuation in K over a plant's envelope -----------------------------------------------

@dataclass(frozen=True)
class ContinuationConfig:
    """Settings of the continuation layer over a plant's envelope (:func:`continue_envelope`;
    its compass search takes its steps, iterations, cap and chunk from the
    :class:`PlantEnvelopeConfig`). ``max_sweeps=0`` leaves the envelope as it is."""

    max_sweeps: int = 10
    """Sweeps at most; it stops earlier after a sweep that moves no K point. A better
    branch spreads one grid step each way per sweep and the mirror brings it to -K at
    once, so 10 sweeps carry it from any K to every K of the 21-point grid."""
    reach: int = 1
    """Grid points on each side of K (and of -K, mirrored) whose angles start at K."""
    warm: bool = True
    """Also run each start from its source's steady field (following the source's branch
    to K, as a laser tracking a drifting K does), not only from the spec's pulse."""
    margin: float = 0.0
    """A start is refined when its steady O exceeds (1 - margin) O*(K) (0: only a start
    that beats O*(K) already)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'max_sweeps', minimum=0)
        checks.counts(self, 'reach')
        checks.non_negative(self, 'margin')
        if not isinstance(self.warm, bool):
            raise ValueError(f'ContinuationConfig.warm must be a bool, got {self.warm!r}')

    def to_dict(self) -> dict:
        return asdict(self)


def _symmetrize(o: np.ndarray, angles: np.ndarray, u: np.ndarray, v: np.ndarray) -> None:
    """In place: at each K the better of its state and the mirror of the state at -K."""
    use = o[::-1] > o
    if use.any():
        twin_a = wrap_angles(mirror_angles(angles[::-1]))
        twin_u, twin_v = mirror_fields(u[::-1], v[::-1])
        o[use] = o[::-1][use]
        angles[use], u[use], v[use] = twin_a[use], twin_u[use], twin_v[use]


def continue_envelope(cavity_cfg: CavityConfig, envelope: dict[str, np.ndarray],
                      cfg: PlantEnvelopeConfig | None = None,
                      continuation: ContinuationConfig | None = None, progress=None
                      ) -> dict[str, np.ndarray]:
    """The envelope improved by continuation in K (never lowered: a K point moves only to
    a better steady state, and the result is symmetric).

    The current angles at every K are first run from the spec's pulse (their fields start
    the warm runs; a better O there is kept). Each sweep then tries, at each K, the angles
    of the ``reach`` grid points on either side and the mirrors of those at -K and its
    neighbours, from the spec's pulse and (``warm``) from the source's field turned with
    it, all K points in one batch. Where the best start beats O*(K) (less ``margin``) it
    is refined by :func:`compass_search` and kept if it beats O*(K); then each K takes the
    better of itself and the mirror of -K. A sweep uses both neighbours at once, so a
    better branch spreads one grid step each way per sweep; the next sweep retries only
    the K points next to one that moved, and the sweeps stop when none moved or after
    ``max_sweeps``.

    Returns the envelope's arrays with ``O_star`` and ``angles`` replaced, plus
    ``O_star_base`` and ``angles_base`` (the input), ``moved_in_sweep`` (n_k,) (the last
    sweep that raised the point, 0: never; -1: the re-run of its own angles) and, per
    sweep, ``sweep_starts``, ``sweep_refined`` and ``sweep_moved``; the input's other
    arrays (``O_star_own``, ``from_mirror``, ``start_O``, ...) describe the base search."""
    cfg = cfg or PlantEnvelopeConfig()
    continuation = continuation or ContinuationConfig()
    k = np.asarray(envelope['K'], float)
    n = k.size
    if not np.allclose(k, -k[::-1], atol=1e-12):
        raise ValueError('continuation needs a K grid symmetric about 0')
    base_o = np.asarray(envelope['O_star'], float)
    base_angles = np.asarray(envelope['angles'], float)
    o, angles = base_o.copy(), wrap_angles(base_angles)
    moved_in = np.zeros(n, int)
    starts, refined, moved = [], [], []
    if continuation.max_sweeps > 0:
        score, (u, v) = steady_scores(cavity_cfg, angles, k, cap=2 * cfg.cap, chunk=cfg.chunk)
        better = score > o + MIN_GAIN
        o[better] = score[better]
        moved_in[better] = -1
        _symmetrize(o, angles, u, v)
        moved_in[(o > base_o) & (moved_in == 0)] = -1
    active = np.ones(n, bool)
    reach = continuation.reach
    for sweep in range(1, continuation.max_sweeps + 1):
        lanes, cand_a, cand_u, cand_v, warm = [], [], [], [], []
        for i in np.flatnonzero(active):
            sources = [(j, False) for d in range(1, reach + 1) for j in (i - d, i + d)]
            sources += [(n - 1 - i + d, True) for d in range(-reach, reach + 1)]
            tried = [angles[i]]
            for j, mirror in sources:
                if not 0 <= j < n:
                    continue
                a = wrap_angles(mirror_angles(angles[j])) if mirror else angles[j]
                if min(angle_distance(a, b) for b in tried) < 1e-9:
                    continue    # the same angles: the same starts
                tried.append(a)
                fu, fv = mirror_fields(u[j], v[j]) if mirror else (u[j], v[j])
                for w in ((False, True) if continuation.warm else (False,)):
                    lanes.append(i)
                    cand_a.append(a)
                    cand_u.append(fu)
                    cand_v.append(fv)
                    warm.append(w)
        starts.append(len(lanes))
        if not lanes:
            refined.append(0)
            moved.append(0)
            break
        lanes, warm = np.array(lanes), np.array(warm)
        cavity = Cavity(cavity_cfg, batch=lanes.size, angles=np.array(cand_a),
                        birefringence=k[lanes])
        if warm.any():
            cavity.set_fields(np.array(cand_u)[warm], np.array(cand_v)[warm],
                              index=np.flatnonzero(warm))
        result = run_to_steady(cavity, 2 * cfg.cap, cfg.chunk)
        score = np.where(result.converged & result.finite, result.O, -np.inf)
        fu, fv = cavity.fields()
        # The best start per K point; refine those that beat O*(K) (less the margin).
        best = {}
        for row, lane in enumerate(lanes):
            if lane not in best or score[row] > score[best[lane]]:
                best[lane] = row
        bar = o * (1 - continuation.margin) if continuation.margin else o + MIN_GAIN
        picks = [(lane, row) for lane, row in best.items() if score[row] > bar[lane]]
        refined.append(len(picks))
        before = o.copy()
        if picks:
            at, rows = (np.array(x) for x in zip(*picks))
            found = compass_search(np.array(cand_a)[rows], k[at], score[rows],
                                   (fu[rows], fv[rows]), cavity_cfg,
                                   first_step=cfg.first_step, min_step=cfg.min_step,
                                   max_iterations=cfg.max_iterations, cap=cfg.cap,
                                   chunk=cfg.chunk, wrap=True, progress=progress)
            gain = found.objective > o[at] + MIN_GAIN
            at = at[gain]
            o[at], angles[at] = found.objective[gain], found.angles[gain]
            u[at], v[at] = found.u[gain], found.v[gain]
            _symmetrize(o, angles, u, v)
        up = o > before
        moved.append(int(up.sum()))
        moved_in[up] = sweep
        if not up.any():
            break
        near = np.convolve(up.astype(int), np.ones(2 * reach + 1, int), 'same') > 0
        active = near | near[::-1]
    out = {**envelope, 'O_star': o, 'angles': angles, 'O_star_base': base_o,
           'angles_base': base_angles, 'moved_in_sweep': moved_in,
           'sweep_starts': np.array(starts, int), 'sweep_refined': np.array(refined, int),
           'sweep_moved': np.array(moved, int)}
    check_symmetric(out)
    return out


# -- the cache of plant envelopes and family draws ------------------------------------------

def cache_dir() -> Path:
    """Where plant envelopes and family draws are cached: ``$DLMPC_CACHE``, else
    ``$XDG_CACHE_HOME/dlmpc_ros``, else ``~/.cache/dlmpc_ros``."""
    if os.environ.get('DLMPC_CACHE'):
        return Path(os.environ['DLMPC_CACHE'])
    base = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(base) / 'dlmpc_ros'


def _settings_key(cfg: PlantEnvelopeConfig, tables: dict[str, np.ndarray],
                  cavity: CavityConfig) -> str:
    """What a cached result depends on besides the plant's physics: the search settings,
    the solver (grid and scheme) and the nominal tables it starts from."""
    solver = {k: v for k, v in cavity.to_dict().items() if k not in PHYSICS_FIELDS}
    digest = hashlib.sha256(json.dumps([cfg.to_dict(), solver], sort_keys=True).encode())
    for key in ('K', *SEED_TABLES):
        if key in tables:
            digest.update(np.ascontiguousarray(tables[key], float).tobytes())
    return digest.hexdigest()[:8]


def _continuation_key(continuation: ContinuationConfig) -> str:
    """The continuation layer's settings, as a short key."""
    text = json.dumps(continuation.to_dict(), sort_keys=True).encode()
    return hashlib.sha256(text).hexdigest()[:8]


def envelope_paths(cavity_cfg: CavityConfig, tables: dict[str, np.ndarray],
                   cfg: PlantEnvelopeConfig | None = None,
                   continuation: ContinuationConfig | None = None,
                   directory: Path | None = None) -> tuple[Path, Path]:
    """Where :func:`cached_plant_envelope` keeps the plant's base envelope and its
    continued envelope."""
    directory = Path(directory or cache_dir()) / 'envelopes'
    settings = _settings_key(cfg or PlantEnvelopeConfig(), tables, cavity_cfg)
    stem = f'{plant_fingerprint(cavity_cfg)}-{settings}'
    key = _continuation_key(continuation or ContinuationConfig())
    return directory / f'{stem}.npz', directory / 'continued' / f'{stem}-{key}.npz'


def continuation_note(envelope: dict[str, np.ndarray]) -> dict:
    """The K points that :func:`continue_envelope` raised, how much and in which sweep,
    and what each sweep did (for the cache's .json note)."""
    base, o = envelope['O_star_base'], envelope['O_star']
    moved = np.flatnonzero(o > base)
    return {
        'mean_O_star_base': float(base.mean()), 'mean_O_star': float(o.mean()),
        'mean_ratio': float(np.mean(o / base)), 'k_points_moved': int(moved.size),
        'moved': [{'K': round(float(envelope['K'][i]), 12), 'O_star_base': float(base[i]),
                   'O_star': float(o[i]), 'ratio': float(o[i] / base[i]),
                   'sweep': int(envelope['moved_in_sweep'][i])} for i in moved],
        'sweeps': [{'starts': int(a), 'refined': int(b), 'moved': int(c)} for a, b, c in
                   zip(envelope['sweep_starts'], envelope['sweep_refined'],
                       envelope['sweep_moved'])],
    }


def cached_plant_envelope(cavity_cfg: CavityConfig, tables: dict[str, np.ndarray],
                          cfg: PlantEnvelopeConfig | None = None,
                          directory: Path | None = None, progress=None,
                          continuation: ContinuationConfig | None = None
                          ) -> dict[str, np.ndarray]:
    """The plant's envelope, continued in K: :func:`plant_envelope` (the base), then
    :func:`continue_envelope` with ``continuation`` (default :class:`ContinuationConfig`;
    ``max_sweeps=0``: the base alone). Each is read from the cache when it was computed
    before for this plant, these settings and these tables; else computed and cached
    (``.npz`` with a ``.json`` note of the plant and the wall time): the base as
    ``envelopes/<plant>-<settings>.npz``, the continued envelope as
    ``envelopes/continued/<plant>-<settings>-<continuation>.npz``, its note listing the
    K points that moved."""
    cfg = cfg or PlantEnvelopeConfig()
    continuation = continuation or ContinuationConfig()
    path, continued = envelope_paths(cavity_cfg, tables, cfg, continuation, directory)
    if continuation.max_sweeps and continued.is_file():
        return read_npz(continued, 'cached continued plant envelope',
                        f'delete {continued} to recompute it')
    if path.is_file():
        envelope = read_npz(path, 'cached plant envelope', f'delete {path} to recompute it')
    else:
        started = time.monotonic()
        envelope = plant_envelope(cavity_cfg, tables, cfg, progress)
        write_npz(path, envelope, {'plant': plant_parameters(cavity_cfg),
                                   'plant_fingerprint': plant_fingerprint(cavity_cfg),
                                   'settings': cfg.to_dict(),
                                   'wall_seconds': round(time.monotonic() - started, 1),
                                   'mean_O_star': float(envelope['O_star'].mean())})
    if not continuation.max_sweeps:
        return envelope
    started = time.monotonic()
    envelope = continue_envelope(cavity_cfg, envelope, cfg, continuation, progress)
    write_npz(continued, envelope, {'plant': plant_parameters(cavity_cfg),
                                    'plant_fingerprint': plant_fingerprint(cavity_cfg),
                                    'settings': cfg.to_dict(),
                                    'continuation': continuation.to_dict(),
                                    'base': path.name,
                                    'wall_seconds': round(time.monotonic() - started, 1),
                                    **continuation_note(envelope)})
    return envelope


#: Draws of one family seed tried before giving up.
MAX_DRAWS = 20


def draw_plant(family: PlantFamily, seed: int, tables: dict[str, np.ndarray],
               cfg: PlantEnvelopeConfig | None = None, directory: Path | None = None,
               max_draws: int = MAX_DRAWS) -> tuple[CavityConfig, int]:
    """Plant ``seed`` of ``family`` and the attempt it took: draws ``(seed, 0)``,
    ``(seed, 1)``, ... until one mode-locks at every K of the envelope grid (some seed
    candidate of :func:`plant_candidates` holds a converged pulse there). The accepted
    attempt is cached, so the same seed gives the same plant at once the next time."""
    cfg = cfg or PlantEnvelopeConfig()
    directory = Path(directory or cache_dir()) / 'draws'
    family_key = hashlib.sha256(json.dumps(family.to_dict(), sort_keys=True).encode())
    settings = _settings_key(cfg, tables, NOMINAL)  # the draws' solver: the nominal cavity's
    path = directory / f'{family_key.hexdigest()[:8]}-{settings}-{seed}.json'
    if path.is_file():
        attempt = int(json.loads(path.read_text())['attempt'])
        return family.draw(seed, attempt), attempt
    for attempt in range(max_draws):
        plant = family.draw(seed, attempt)
        if mode_locks(plant_candidates(plant, tables, cfg)):
            directory.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps({'seed': seed, 'attempt': attempt,
                                        'plant': plant_parameters(plant)}, indent=2))
            return plant, attempt
    raise ValueError(f'no plant of family seed {seed} mode-locks at every K in {max_draws} '
                     'draws; widen the family or choose another seed')


# -- tasks for dlmpc-evaluate and dlmpc-data (run by dlmpc_ros.scaleout) -------------------

@dataclass(frozen=True)
class PlantTask:
    """A family draw (``plant`` None: draw ``seed`` of ``family``) or an envelope (of
    ``plant``), with the nominal tables it starts from."""

    tables_path: str
    """The nominal baseline tables (``models/oracle.npz``)."""
    cache: str | None = None
    """Cache directory (None: :func:`cache_dir`)."""
    settings: PlantEnvelopeConfig = PlantEnvelopeConfig()
    """The envelope search's settings."""
    family: PlantFamily = PlantFamily()
    """The family of a draw."""
    seed: int = 0
    """The family seed of a draw."""
    plant: dict | None = None
    """The physical parameters of an envelope's plant."""


def draw_task(task: PlantTask) -> dict:
    """``{'plant': parameters, 'attempt': n}`` of family seed ``task.seed``."""
    from dlmpc_ros.learning.tables import load_baselines
    plant, attempt = draw_plant(task.family, task.seed, load_baselines(task.tables_path),
                                task.settings, task.cache and Path(task.cache))
    return {'plant': plant_parameters(plant), 'attempt': attempt}


def envelope_task(task: PlantTask) -> dict[str, np.ndarray]:
    """The (cached) continued envelope of ``task.plant`` (:func:`cached_plant_envelope`)."""
    from dlmpc_ros.learning.tables import load_baselines
    cavity = replace(NOMINAL, **(task.plant or {}))
    return cached_plant_envelope(cavity, load_baselines(task.tables_path), task.settings,
                                 task.cache and Path(task.cache))
