"""The oracle envelope O*(K): the best steady-state objective and its angles per K.

Per K of the sweep's grid, the best steady states of the sweep are re-run from the spec's
initial pulse, and the best of them is refined by the batched compass search of
:mod:`dlmpc_ros.training.search` (angles kept in [-pi/2, pi/2)). The envelope keeps, per
K, the better of the refined optimum and the sweep's best point (which may lie on a
branch reached only by continuation in K). It is written to ``data/oracle.npz``
(:mod:`dlmpc_ros.learning.tables` reads it).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.learning.tables import write_npz
from dlmpc_ros.training import shards
from dlmpc_ros.training.search import compass_search, steady_scores


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
                    cfg: OracleConfig, progress=None) -> dict[str, np.ndarray]:
    """Compute the envelope from sweep data; returns arrays over the K grid."""
    k_grid = np.unique(sweep['K'])
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
    dirs = rng.standard_normal((n_k, cfg.check_directions, 4))
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


def generate_oracle(sweep_dir: Path, out_path: Path, cavity_cfg: CavityConfig,
                    cfg: OracleConfig, show_progress: bool = True) -> dict:
    """``dlmpc-data oracle``: the envelope of the sweep in ``sweep_dir``, written to
    ``out_path`` with a .json note; returns the note."""
    started = time.monotonic()
    sweep = shards.load_dataset(sweep_dir)

    def progress(iteration, mean_o, active):
        if show_progress:
            print(f'oracle: iteration {iteration:2d}  mean O* {mean_o:.4f}  K points still '
                  f'moving {active}', flush=True)

    env = refine_envelope(sweep, cavity_cfg, cfg, progress)
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
