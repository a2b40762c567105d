"""The DL-MPC's own closed-loop data on training plants of the family: what the
steady-response predictor is trained on besides the rotation data (DAgger's aggregation).

The rotation data (:mod:`dlmpc_ros.training.response`) holds steady states along scans of
the rotation from the curve's own; the controller visits other states (the tracker's
turns, a remembered rotation, K drifting under it). Here the exploring DL-MPC
(:attr:`~dlmpc_ros.control.dlmpc_config.PlannerConfig.explore`: every plan a random
turn within the trust radius, taken back if O falls, as ``bringup --controller explore``
records a calibration bag) runs on family plants ``first_seed`` on (the rotation data's
own plants: none of the evaluation's 1-8 or 101-108), under a random walk of K of
``drift_seed`` (no evaluation seed), fast mode; every run's settled states become pairs as
``dlmpc-train adapt`` makes them from a bag (:func:`dlmpc_ros.training.adapt.laser_pairs`).
A run sees E, M and its own angles only; K and the plant's parameters stay in the
simulator. Measured (``bench/results/closed_loop_retraining.md``): a new ensemble fit to
the rotation pairs and these pairs plans as well as the rotation pairs' alone on the
development plants, and fine-tuning the pretrained ensemble on these pairs alone plans
worse.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.scaleout import TaskFailure, run_tasks


@dataclass(frozen=True)
class ClosedLoopConfig:
    """Which closed-loop runs train the predictor (times in round trips)."""

    plants: int = 40
    """Family plants run (seeds ``first_seed`` on)."""
    first_seed: int = 2001
    """Family seed of the first plant."""
    validation_plants: int = 8
    """The last this many plants' pairs only measure the fit (held out of it)."""
    round_trips: int = 20000
    """Round trips of each run."""
    drift_seed: int = 77
    """Seed of the random walk of K."""

    def __post_init__(self) -> None:
        checks.counts(self, 'plants', 'round_trips')
        checks.counts(self, 'first_seed', 'validation_plants', 'drift_seed', minimum=0)
        if self.validation_plants >= self.plants:
            raise ValueError(f'ClosedLoopConfig.validation_plants ({self.validation_plants}) '
                             f'must be under plants ({self.plants})')

    @property
    def seeds(self) -> list[int]:
        return list(range(self.first_seed, self.first_seed + self.plants))

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class RunJob:
    """One closed-loop run of ``config``: family plant ``plant_seed`` with the models of
    ``models_dir``, exploring or planning."""

    plant_seed: int
    models_dir: str
    explore: bool
    config: ClosedLoopConfig


def closed_loop_run(job: RunJob) -> dict[str, np.ndarray]:
    """The control periods of one run: ``round_trip`` (n,), ``E``, ``M`` (n,) and
    ``angles`` (n, 4), where the laser measured a finite, positive E."""
    from dlmpc_ros.control.dlmpc_config import DLMPCConfig, PlannerConfig
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.control.step import AngleLimits
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.training.envelope import PlantTask, draw_task
    models = Path(job.models_dir)
    plant = draw_task(PlantTask(str(models / 'oracle.npz'), seed=job.plant_seed))['plant']
    spec = RunSpec('random_walk', job.config.drift_seed, 'dlmpc',
                   round_trips=job.config.round_trips, plant=plant)
    controller = load_dlmpc(models, DLMPCConfig(limits=AngleLimits(max_step=spec.max_step),
                                                planner=PlannerConfig(explore=job.explore)))
    record = run_fast(spec, models, controller)
    i = np.searchsorted(record.round_trip, record.control_round_trip)
    keep = np.isfinite(record.E[i]) & np.isfinite(record.M[i]) & (record.E[i] > 0)
    i = i[keep]
    return {'round_trip': record.round_trip[i], 'E': record.E[i], 'M': record.M[i],
            'angles': record.angles[i]}


def closed_loop_runs(cfg: ClosedLoopConfig, models_dir: Path, directory: Path,
                     workers: int = 1, explore: bool = True, show_progress: bool = True
                     ) -> list[dict[str, np.ndarray]]:
    """The runs of ``cfg.seeds`` with the models of ``models_dir`` (in seed order), each
    saved in ``directory`` as it finishes and read back from there when made before."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    tag = f"{cfg.round_trips}-{cfg.drift_seed}-{'explore' if explore else 'plan'}"
    path = {s: directory / f'{s}-{tag}.npz' for s in cfg.seeds}
    todo = [s for s in cfg.seeds if not path[s].is_file()]
    jobs = [RunJob(s, str(models_dir), explore, cfg) for s in todo]

    def save(index: int, run: dict | TaskFailure) -> None:
        if not isinstance(run, TaskFailure):
            np.savez(path[todo[index]], **run)
    made = run_tasks(closed_loop_run, jobs, workers, desc='closed-loop runs',
                     show_progress=show_progress, on_result=save)
    failed = [str(r) for r in made if isinstance(r, TaskFailure)]
    if failed:
        raise RuntimeError('closed-loop runs failed (the others are saved; run again to '
                           'resume): ' + '; '.join(failed))
    return [dict(np.load(path[s])) for s in cfg.seeds]
