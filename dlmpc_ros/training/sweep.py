"""Steady-state sweep: K over [-0.3, 0.3] crossed with space-filling angle sets.

Each *chain* is one angle set swept through the K grid by continuation (ascending for
even chains, descending for odd ones, so both branches of hysteresis are sampled): the
field is warm-started from the previous K's final state, as a laser whose birefringence
drifts slowly would be. Each (angle set, K) point runs until the spec's steady-state rule
holds or a round-trip cap. Chains run as lanes of a batched cavity, one batch per shard
(a finished lane takes the next chain); the shards are independent tasks. Angle sets come
from a scrambled Sobol sequence over [-pi/2, pi/2)^4 (every element is pi-periodic), then
a refinement phase perturbs the angle sets that reached the highest objective.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.stats import qmc

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import BIREFRINGENCE_RANGE, CavityConfig
from dlmpc_ros.scaleout import TaskFailure, run_tasks
from dlmpc_ros.training import shards

FIELDS = ('chain', 'K', 'alpha', 'E', 'M', 'O', 'energy', 'peak', 'pulses', 'converged',
          'finite', 'round_trips')


@dataclass(frozen=True)
class SweepConfig:
    """Settings of the steady-state sweep."""

    sobol_sets: int = 1280
    """Space-filling angle sets (a multiple of ``chains_per_shard``)."""
    refine_sets: int = 384
    """Angle sets drawn around the best ones found by the Sobol phase."""
    refine_sigma: float = 0.08
    """Standard deviation of the refinement perturbation [rad]."""
    k_points: int = 61
    """K grid points over [-0.3, 0.3] per chain."""
    first_cap: int = 300
    """Round-trip cap of a chain's first point (a cold start from sech)."""
    cap: int = 100
    """Round-trip cap of the following, warm-started points."""
    chunk: int = 5
    """Round trips between two steady-state checks."""
    batch: int = 256
    """Lasers simulated at once."""
    chains_per_shard: int = 128
    """Chains stored per shard file."""
    seed: int = 0
    """Seed of the Sobol scrambling and the refinement draws."""

    def __post_init__(self) -> None:
        checks.counts(self, 'sobol_sets', 'k_points', 'first_cap', 'cap', 'chunk', 'batch',
                      'chains_per_shard')
        checks.counts(self, 'refine_sets', 'seed', minimum=0)
        checks.positive(self, 'refine_sigma')
        if self.sobol_sets % self.chains_per_shard:
            raise ValueError('SweepConfig.sobol_sets must be a multiple of chains_per_shard')

    def k_grid(self) -> np.ndarray:
        return np.linspace(*BIREFRINGENCE_RANGE, self.k_points)

    def to_dict(self) -> dict:
        return asdict(self)


def sobol_angles(count: int, seed: int) -> np.ndarray:
    """(count, 4) scrambled Sobol angle sets in [-pi/2, pi/2)."""
    sampler = qmc.Sobol(d=4, scramble=True, seed=seed)
    with warnings.catch_warnings():  # any count is fine here: the first points of the
        warnings.simplefilter('ignore', UserWarning)  # sequence still fill the cube evenly
        points = sampler.random(count)
    return (points - 0.5) * math.pi


def refine_angles(best: np.ndarray, count: int, sigma: float, seed: int) -> np.ndarray:
    """(count, 4) perturbations of the rows of ``best``, wrapped into [-pi/2, pi/2)."""
    rng = np.random.default_rng(seed + 1)
    picks = best[rng.integers(0, best.shape[0], count)]
    return wrap_angles(picks + sigma * rng.standard_normal(picks.shape))


def run_chains(angle_sets: np.ndarray, chain_ids: np.ndarray, cfg: SweepConfig,
               cavity_cfg: CavityConfig, on_chain: Callable[[int, dict], None],
               progress: Callable[[int], None] | None = None) -> None:
    """Run chains through the K grid; calls ``on_chain(chain_id, samples)`` as each ends.

    ``samples`` maps :data:`FIELDS` to arrays with one row per K point.
    """
    k_grid = cfg.k_grid()
    queue = list(range(len(chain_ids)))
    lanes = min(cfg.batch, len(queue))
    if lanes == 0:
        return
    cavity = Cavity(cavity_cfg, batch=lanes)
    lane_job = np.full(lanes, -1)       # index into chain_ids / angle_sets
    lane_point = np.zeros(lanes, int)   # position along the K grid
    lane_trips = np.zeros(lanes, int)   # round trips at this point
    records: dict[int, dict[str, list]] = {}

    def k_order(job: int) -> np.ndarray:
        return k_grid if chain_ids[job] % 2 == 0 else k_grid[::-1]

    def start(lane: int) -> None:
        job = queue.pop(0)
        lane_job[lane], lane_point[lane], lane_trips[lane] = job, 0, 0
        cavity.set_angles(angle_sets[job], index=[lane])
        cavity.set_birefringence(k_order(job)[0], index=[lane])
        cavity.reset([lane])
        records[job] = {name: [] for name in FIELDS}

    for lane in range(lanes):
        start(lane)
    while (lane_job >= 0).any():
        last = cavity.run(cfg.chunk).last()
        lane_trips += cfg.chunk
        for lane in np.flatnonzero(lane_job >= 0):
            job = lane_job[lane]
            cap = cfg.first_cap if lane_point[lane] == 0 else cfg.cap
            blown = not last.finite[lane]
            if not (last.converged[lane] or blown or lane_trips[lane] >= cap):
                continue
            rec = records[job]
            rec['chain'].append(chain_ids[job])
            rec['K'].append(k_order(job)[lane_point[lane]])
            rec['alpha'].append(angle_sets[job])
            for name in ('E', 'M', 'O', 'energy', 'peak', 'pulses', 'converged', 'finite'):
                rec[name].append(getattr(last, name)[lane])
            rec['round_trips'].append(lane_trips[lane])
            if blown:
                cavity.reset([lane])
            lane_point[lane] += 1
            lane_trips[lane] = 0
            if progress is not None:
                progress(1)
            if lane_point[lane] < len(k_grid):
                cavity.set_birefringence(k_order(job)[lane_point[lane]], index=[lane])
                continue
            on_chain(int(chain_ids[job]), {k: np.asarray(v) for k, v in rec.items()})
            del records[job]
            if queue:
                start(lane)
            else:
                lane_job[lane] = -1


def best_angle_sets(data: dict[str, np.ndarray], count: int) -> np.ndarray:
    """Angle sets of the ``count`` chains with the highest mean steady O over K."""
    chains = np.unique(data['chain'])
    score = np.array([np.nanmean(np.where(data['converged'][data['chain'] == c],
                                          data['O'][data['chain'] == c], 0.0))
                      for c in chains])
    top = chains[np.argsort(score)[::-1][:count]]
    return np.stack([data['alpha'][data['chain'] == c][0] for c in top])


@dataclass(frozen=True)
class ShardTask:
    """One shard of the sweep: its chains, run and written by a worker."""

    directory: str
    shard: int
    chain_ids: np.ndarray
    """(c,) chain ids of the shard, in order."""
    angle_sets: np.ndarray
    """(c, 4) their angle sets [rad]."""
    cfg: SweepConfig
    cavity: CavityConfig


def run_shard(task: ShardTask) -> int:
    """Run the task's chains (one batch of lanes) and write its shard; returns the points.

    A chain's states depend on its own angle set and K order only (every lane of the
    batch is an independent laser), so any split into shards gives the same data."""
    done: dict[int, dict] = {}
    run_chains(task.angle_sets, task.chain_ids, task.cfg, task.cavity,
               lambda chain, samples: done.__setitem__(chain, samples))
    parts = [done[int(c)] for c in task.chain_ids]
    shards.write_shard(Path(task.directory), task.shard,
                       {k: np.concatenate([p[k] for p in parts]) for k in FIELDS})
    return int(sum(p['K'].size for p in parts))


def generate_sweep(directory, cfg: SweepConfig, cavity_cfg: CavityConfig,
                   show_progress: bool = True, workers: int = 1,
                   scheduler: str | None = None) -> dict:
    """Run (or resume) the sweep into ``directory``, one task per shard (serially, or on
    Dask: :func:`dlmpc_ros.scaleout.run_tasks`; the workers write the shards, so a remote
    cluster must share ``directory``); returns the dataset's metadata."""
    directory = Path(directory)
    shards.check_metadata(directory, {'sweep': cfg.to_dict(), 'cavity': cavity_cfg.to_dict()})
    started = time.monotonic()
    sobol = sobol_angles(cfg.sobol_sets, cfg.seed)
    n_sobol = sobol.shape[0]
    per = cfg.chains_per_shard

    def run_phase(angle_sets: np.ndarray, first_id: int, desc: str) -> None:
        ids = first_id + np.arange(angle_sets.shape[0])
        tasks = [ShardTask(str(directory), int(shard), ids[ids // per == shard],
                           angle_sets[ids // per == shard], cfg, cavity_cfg)
                 for shard in np.unique(ids // per)
                 if not shards.shard_path(directory, int(shard)).exists()]
        failed = [r for r in run_tasks(run_shard, tasks, workers, scheduler, desc=desc,
                                       show_progress=show_progress)
                  if isinstance(r, TaskFailure)]
        if failed:
            raise RuntimeError('sweep shards failed (the others are written; run again to '
                               'resume): ' + '; '.join(str(f) for f in failed))

    run_phase(sobol, 0, 'sweep shards (Sobol)')
    if cfg.refine_sets:
        sobol_data = shards.load_dataset(directory)
        sobol_data = {k: v[sobol_data['chain'] < n_sobol] for k, v in sobol_data.items()}
        best = best_angle_sets(sobol_data, max(8, cfg.refine_sets // 8))
        run_phase(refine_angles(best, cfg.refine_sets, cfg.refine_sigma, cfg.seed), n_sobol,
                  'sweep shards (refinement)')
    data = shards.load_dataset(directory)
    return shards.finish_metadata(directory, {
        'wall_seconds_this_run': round(time.monotonic() - started, 1),
        'converged_fraction': float(data['converged'].mean()),
        'round_trips_total': int(data['round_trips'].sum()),
    })
