"""The oracle envelope O*(K): the best steady-state objective and its angles per K.

Per K of the sweep's grid, the best steady states of the sweep are re-run from the spec's
initial pulse, and the best of them is refined by a batched compass (pattern) search on
the steady-state O: each iteration tries +-step on every angle, warm-started from the
current best field; a better converged neighbor is taken, otherwise the step is halved,
down to ``min_step``. The envelope keeps, per K, the better of the refined optimum and the
sweep's best point (which may lie on a branch reached only by continuation in K).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.learning.sweep import wrap_angles


@dataclass(frozen=True)
class OracleConfig:
    """Settings of the envelope refinement (angles in radians)."""

    candidates: int = 4
    first_step: float = 0.08
    min_step: float = 0.005
    max_iterations: int = 40
    cap: int = 300
    chunk: int = 5
    check_directions: int = 16
    seed: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


def _steady(cfg: CavityConfig, angles: np.ndarray, k: np.ndarray, fields=None,
            cap: int = 300, chunk: int = 5):
    cavity = Cavity(cfg, batch=angles.shape[0], angles=angles, birefringence=k)
    if fields is not None:
        cavity.set_fields(*fields)
    result = run_to_steady(cavity, cap, chunk)
    score = np.where(result.converged & result.finite, result.O, -np.inf)
    return score, cavity.fields()


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
    score, (u, v) = _steady(cavity_cfg, cand_angles.reshape(-1, 4), flat_k, cap=cfg.cap,
                            chunk=cfg.chunk)
    score = score.reshape(n_k, cfg.candidates)
    pick = np.argmax(score, axis=1)
    rows = np.arange(n_k) * cfg.candidates + pick
    best_angles = cand_angles[np.arange(n_k), pick].copy()
    best_o = score[np.arange(n_k), pick].copy()
    best_u, best_v = u[rows].copy(), v[rows].copy()
    start_o = best_o.copy()
    step = np.full(n_k, cfg.first_step)
    directions = np.concatenate([np.eye(4), -np.eye(4)])  # (8, 4)
    iterations = 0
    while (step >= cfg.min_step).any() and iterations < cfg.max_iterations:
        iterations += 1
        trial = wrap_angles(best_angles[:, None, :] + step[:, None, None] * directions)
        score, (u, v) = _steady(cavity_cfg, trial.reshape(-1, 4), np.repeat(k_grid, 8),
                                (np.repeat(best_u, 8, axis=0), np.repeat(best_v, 8, axis=0)),
                                cfg.cap, cfg.chunk)
        score = score.reshape(n_k, 8)
        j = np.argmax(score, axis=1)
        better = (score[np.arange(n_k), j] > best_o + 1e-7) & (step >= cfg.min_step)
        rows = np.arange(n_k) * 8 + j
        best_angles[better] = trial[better, j[better]]
        best_o[better] = score[better, j[better]]
        best_u[better], best_v[better] = u[rows][better], v[rows][better]
        step[~better] /= 2
        if progress is not None:
            progress(iterations, float(np.mean(best_o)), int((step >= cfg.min_step).sum()))
    # How close to a local maximum: random directions at twice the final step.
    rng = np.random.default_rng(cfg.seed)
    dirs = rng.standard_normal((n_k, cfg.check_directions, 4))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    probe = wrap_angles(best_angles[:, None, :] + 2 * cfg.min_step * dirs)
    score, _ = _steady(cavity_cfg, probe.reshape(-1, 4), np.repeat(k_grid, cfg.check_directions),
                       (np.repeat(best_u, cfg.check_directions, axis=0),
                        np.repeat(best_v, cfg.check_directions, axis=0)), cfg.cap, cfg.chunk)
    probe_gain = score.reshape(n_k, cfg.check_directions).max(axis=1) / best_o - 1
    use_sweep = sweep_best_o > best_o
    return {
        'K': k_grid,
        'O_star': np.where(use_sweep, sweep_best_o, best_o),
        'angles': np.where(use_sweep[:, None], sweep_best_angles, best_angles),
        'from_sweep': use_sweep,
        'refined_O': best_o, 'refined_angles': best_angles, 'start_O': start_o,
        'sweep_best_O': sweep_best_o, 'probe_gain': probe_gain,
        'iterations': np.array(iterations),
    }


def save_envelope(path: Path, envelope: dict[str, np.ndarray], meta: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **envelope)
    path.with_suffix('.json').write_text(json.dumps(meta, indent=2))


def load_envelope(path: Path) -> dict[str, np.ndarray]:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f'oracle envelope {path} is missing; run `dlmpc-data oracle`')
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def envelope_angles(envelope: dict[str, np.ndarray], k: np.ndarray) -> np.ndarray:
    """Oracle angles at the grid K nearest to each ``k``, (..., 4)."""
    k = np.asarray(k, float)
    index = np.abs(envelope['K'][None, :] - k.reshape(-1, 1)).argmin(axis=1)
    return envelope['angles'][index].reshape(*k.shape, 4)


def envelope_objective(envelope: dict[str, np.ndarray], k: np.ndarray) -> np.ndarray:
    """O*(K) linearly interpolated over the grid."""
    return np.interp(np.asarray(k, float), envelope['K'], envelope['O_star'])


def generate_oracle(sweep_dir: Path, out_path: Path, cavity_cfg: CavityConfig,
                    cfg: OracleConfig, show_progress: bool = True) -> dict:
    from dlmpc_ros.learning import shards

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
    save_envelope(out_path, env, meta)
    return meta
