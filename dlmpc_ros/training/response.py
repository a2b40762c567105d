"""How the tracking curve's rotation moves the laser, over the plant family: the data of
the DL-MPC's steady-response predictor (:mod:`dlmpc_ros.learning.response`).

A lab's laser is never the nominal cavity, and on another cavity the best angles are
mostly the curve turned by some angle theta (all four elements together; see
:mod:`dlmpc_ros.control.rotation_planner`): a few hundredths of a radian on some lasers, 0.2 to
0.4 rad with a 30 % higher objective on others, and with a cliff on one side where the
pulse is lost. Which way and how far shows in what the laser measures there (E and M).

For each plant drawn from the family (:class:`~dlmpc_ros.core.plants.PlantFamily`, seeds
``first_seed`` on: none of the evaluation's), at each K of ``k_values`` (the curve's good
side, K < 0: the mirror twin serves K > 0 with the same curve parameter, so half the K
range is all the data needs) and each curve point ``u = K + offset`` (the tracker's
estimate is never exactly K), the laser settles at the curve point from the spec's
pulse, then the rotation is stepped away from 0 by ``step`` every ``hold`` round trips,
``steps`` times, one lane each way (continuation: the laser carries its pulse from step
to step, as under the controller). Every step gives a row ``(plant, K, u, theta, E, M)``
of the steady state at its end. The plants' parameters stay in the data only as an index:
no model reads them.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.fingerprint import fingerprint_arrays
from dlmpc_ros.core.plants import NOMINAL, PlantFamily
from dlmpc_ros.scaleout import TaskFailure, run_tasks
from dlmpc_ros.training import shards

#: Columns of the data, in order.
COLUMNS = ('plant', 'K', 'u', 'theta', 'E', 'M')
#: Lowest log-ratio of O the predictor is trained to predict: a turn that loses the pulse (O
#: falls to a tenth or less).
LOST = float(np.log(0.1))


@dataclass(frozen=True)
class ResponseConfig:
    """Settings of the steady-response data (times in round trips, angles in rad)."""

    plants: int = 80
    """Plants drawn from the family."""
    first_seed: int = 2001
    """Family seed of the first plant (the next plants take the next seeds)."""
    k_values: tuple[float, ...] = (-0.28, -0.22, -0.16, -0.10, -0.04)
    """Birefringences (the curve's good side)."""
    offsets: tuple[float, ...] = (-0.04, 0.0, 0.04)
    """Curve points u = K + offset (the estimate's error)."""
    step: float = 0.025
    """Rotation step."""
    steps: int = 20
    """Steps each way."""
    hold: int = 40
    """Round trips per step."""
    settle: int = 300
    """Round trips at the curve point before the first step."""
    plants_per_task: int = 4
    """Plants per task of the scale-out."""
    nominal_only: bool = False
    """Every plant the nominal cavity (the nominal-only pretraining of the ablation)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'plants', 'steps', 'hold', 'settle', 'plants_per_task')
        checks.counts(self, 'first_seed', minimum=0)
        checks.positive(self, 'step')
        if not self.k_values or not self.offsets:
            raise ValueError('ResponseConfig needs k_values and offsets')

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ResponseTask:
    """The plants ``seeds`` of the data, with the curve to turn."""

    config: ResponseConfig
    seeds: tuple[int, ...]
    grid: np.ndarray
    angles: np.ndarray


def curve_angles(grid: np.ndarray, angles: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The curve's angles (n, 4) [rad] at the parameters ``u`` (n,) (clipped to the grid)."""
    u = np.clip(np.asarray(u, float), grid[0], grid[-1])
    return np.stack([np.interp(u, grid, angles[:, j]) for j in range(4)], axis=1)


def response_rows(task: ResponseTask) -> np.ndarray:
    """The rows ``(m, 6)`` of :data:`COLUMNS` of the task's plants."""
    family = PlantFamily()
    return np.concatenate([
        plant_rows(NOMINAL if task.config.nominal_only else family.draw(seed), seed,
                   task.config, task.grid, task.angles)
        for seed in task.seeds])


def plant_rows(plant: CavityConfig, label: int, cfg: ResponseConfig, grid: np.ndarray,
               angles: np.ndarray) -> np.ndarray:
    """The rows ``(m, 6)`` of :data:`COLUMNS` of one plant (``label`` in the plant column):
    every K and curve point of ``cfg``, the rotation stepped away from 0 both ways."""
    k = np.repeat(np.asarray(cfg.k_values, float), len(cfg.offsets))
    u = k + np.tile(np.asarray(cfg.offsets, float), len(cfg.k_values))
    k, u = np.r_[k, k], np.r_[u, u]                       # one lane each way
    way = np.repeat([1.0, -1.0], k.size // 2)
    base = curve_angles(grid, angles, u)
    cavity = Cavity(plant, batch=k.size, angles=base, birefringence=k)
    cavity.run(cfg.settle)
    rows = []
    for i in range(cfg.steps + 1):
        theta = way * cfg.step * i
        if i:
            cavity.set_angles(base + theta[:, None])
            result = cavity.run(cfg.hold).last()
        else:
            result = cavity.run(1).last()
        keep = way > 0 if i == 0 else np.ones(k.size, bool)  # theta = 0 once
        rows.append(np.stack([np.full(k.size, label), k, u, theta, result.E, result.M],
                             axis=1)[keep])
    return np.concatenate(rows)


@dataclass(frozen=True)
class ShardJob:
    """One shard of the data: a task and where to write it."""

    directory: str
    index: int
    task: ResponseTask


def run_response_shard(job: ShardJob) -> int:
    """Simulate the job's plants and write their shard; returns its row count."""
    rows = response_rows(job.task)
    shards.write_shard(Path(job.directory), job.index,
                       {name: rows[:, i] for i, name in enumerate(COLUMNS)})
    return int(rows.shape[0])


def generate_response(directory: Path, cfg: ResponseConfig, grid: np.ndarray,
                      angles: np.ndarray, show_progress: bool = True, workers: int = 1,
                      scheduler: str | None = None) -> dict:
    """Make (or resume) the steady-response data of the curve ``(grid, angles)`` into
    ``directory``, ``plants_per_task`` plants per shard, serially or on Dask
    (:func:`dlmpc_ros.scaleout.run_tasks`); returns the dataset's metadata."""
    directory = Path(directory)
    grid, angles = np.asarray(grid, float), np.asarray(angles, float)
    shards.check_metadata(directory, {'response': cfg.to_dict(),
                                      'curve': fingerprint_arrays({'grid': grid,
                                                                   'angles': angles})})
    started = time.monotonic()
    seeds = cfg.first_seed + np.arange(cfg.plants)
    per = cfg.plants_per_task
    jobs = [ShardJob(str(directory), i, ResponseTask(cfg, tuple(int(s) for s in chunk), grid,
                                                     angles))
            for i, chunk in enumerate(np.split(seeds, range(per, seeds.size, per)))
            if not shards.shard_path(directory, i).exists()]
    failed = [r for r in run_tasks(run_response_shard, jobs, workers, scheduler,
                                   desc='response shards', show_progress=show_progress)
              if isinstance(r, TaskFailure)]
    if failed:
        raise RuntimeError('response shards failed (the others are written; run again to '
                           'resume): ' + '; '.join(str(f) for f in failed))
    return shards.finish_metadata(directory, {
        'wall_seconds_this_run': round(time.monotonic() - started, 1)})
