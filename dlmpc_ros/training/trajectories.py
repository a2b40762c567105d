"""Drifting-K trajectories for the predictor and the estimator, one row per control period.

Many lasers run at once, warm-started throughout. Each has its own seeded drift scenario
(K changes every round trip) and an exploring angle policy evaluated every control period
of P round trips: with probability ``p_retarget`` a new target near the oracle angles of
the current K, with probability ``p_random`` uniformly random angles, otherwise the same
target; a small dither is added on every period. (The trained K-to-angles map cannot
choose the angles here, since it is trained on this data's estimator; the oracle angles
stand in for it.) Rows hold the measured ``(E, M, alpha)`` at the end of each period and
the true K only as an evaluation label.

Segments of ``segment_periods`` periods are stored as shards together with the fields at
their end, so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import make_scenario
from dlmpc_ros.learning.tables import envelope_angles
from dlmpc_ros.training import shards


@dataclass(frozen=True)
class TrajectoryConfig:
    """Settings of the trajectory generation (periods and times in round trips)."""

    train_lasers: int = 64
    """Lasers whose rows train the models."""
    test_lasers: int = 16
    """Held-out lasers (validation and test)."""
    round_trips: int = 20000
    """Round trips per laser."""
    period: int = 10
    """Control period P: one row per P round trips."""
    p_retarget: float = 0.06
    """Chance per period of a new target near the oracle angles of the current K."""
    p_random: float = 0.01
    """Chance per period of uniformly random angles."""
    target_sigma: float = 0.12
    """Spread of a new target around the oracle angles [rad]."""
    dither_sigma: float = 0.01
    """Dither added to the target every period [rad]."""
    segment_periods: int = 500
    """Periods per shard (the unit of resuming)."""
    seed: int = 0
    """Seed of the angle policy and of the lanes' drift seeds."""

    def __post_init__(self) -> None:
        checks.counts(self, 'round_trips', 'period', 'segment_periods')
        checks.counts(self, 'train_lasers', 'test_lasers', 'seed', minimum=0)
        if self.train_lasers + self.test_lasers < 1:
            raise ValueError('TrajectoryConfig needs at least one laser')
        checks.non_negative(self, 'p_retarget', 'p_random', 'target_sigma', 'dither_sigma')
        if self.p_retarget + self.p_random > 1:
            raise ValueError('TrajectoryConfig.p_retarget + p_random must be <= 1')

    def to_dict(self) -> dict:
        return asdict(self)


def scenario_for(index: int, seed: int):
    """A seeded drift scenario; training lasers use seeds 1000+, held-out ones 5000+."""
    rng = np.random.default_rng(seed)
    kind = index % 3
    if kind == 0:
        return make_scenario('random_walk', seed=seed, sigma=float(rng.uniform(0.06, 0.14)),
                             correlation_time=float(rng.uniform(1000, 5000)),
                             offset=float(rng.uniform(-0.1, 0.1)))
    if kind == 1:
        amplitude = float(rng.uniform(0.1, 0.28))
        return make_scenario('sinusoidal', amplitude=amplitude,
                             offset=float(rng.uniform(-1, 1) * (0.3 - amplitude)),
                             period=float(rng.uniform(3000, 15000)),
                             phase=float(rng.uniform(0, 2 * math.pi)))
    return make_scenario('chirp', period=float(rng.uniform(10000, 30000)),
                         phase=float(rng.uniform(0, 2 * math.pi)))


def lane_seeds(cfg: TrajectoryConfig) -> tuple[np.ndarray, np.ndarray]:
    """Drift seeds of every lane and whether the lane is held out for testing."""
    train = 1000 + cfg.seed * 10000 + np.arange(cfg.train_lasers)
    test = 5000 + cfg.seed * 10000 + np.arange(cfg.test_lasers)
    return np.concatenate([train, test]), np.r_[np.zeros(train.size, bool),
                                                np.ones(test.size, bool)]


def generate_trajectories(directory: Path, envelope: dict[str, np.ndarray],
                          cavity_cfg: CavityConfig, cfg: TrajectoryConfig,
                          show_progress: bool = True) -> dict:
    """Run (or resume) trajectory generation into ``directory``; returns its metadata."""
    directory = Path(directory)
    shards.check_metadata(directory, {'trajectories': cfg.to_dict(),
                                      'cavity': cavity_cfg.to_dict()})
    started = time.monotonic()
    seeds, held_out = lane_seeds(cfg)
    lanes = seeds.size
    scenarios = [scenario_for(i, int(s)) for i, s in enumerate(seeds)]
    periods = cfg.round_trips // cfg.period
    n_segments = math.ceil(periods / cfg.segment_periods)
    rng = np.random.default_rng(cfg.seed)
    k0 = np.array([sc(0) for sc in scenarios])
    target = envelope_angles(envelope, k0)
    cavity = Cavity(cavity_cfg, batch=lanes, angles=target, birefringence=k0)
    first = 0
    while first < n_segments and shards.shard_path(directory, first).exists():
        first += 1
    if first:  # resume from the fields, targets and generator saved with the last shard
        with np.load(shards.shard_path(directory, first - 1)) as last:
            cavity.set_fields(last['end_u'], last['end_v'])
            target = last['end_target']
            cavity.round_trip = int(last['end_round_trip'])
            rng.bit_generator.state = json.loads(str(last['end_rng']))
    bar = tqdm(total=periods, initial=first * cfg.segment_periods, unit='period',
               desc='trajectories', disable=not show_progress)
    for segment in range(first, n_segments):
        start_period = segment * cfg.segment_periods
        count = min(cfg.segment_periods, periods - start_period)
        rows = {name: np.zeros((lanes, count)) for name in ('E', 'M', 'O', 'K', 'converged')}
        rows['alpha'] = np.zeros((lanes, count, 4))
        for j in range(count):
            draw = rng.random(lanes)
            k_now = np.array([sc(cavity.round_trip) for sc in scenarios])
            retarget = draw < cfg.p_retarget
            random = (draw >= cfg.p_retarget) & (draw < cfg.p_retarget + cfg.p_random)
            target[retarget] = wrap_angles(envelope_angles(envelope, k_now[retarget])
                                           + cfg.target_sigma
                                           * rng.standard_normal((retarget.sum(), 4)))
            target[random] = rng.uniform(-math.pi / 2, math.pi / 2, (random.sum(), 4))
            applied = wrap_angles(target + cfg.dither_sigma * rng.standard_normal(target.shape))
            cavity.set_angles(applied)
            k_sum = np.zeros(lanes)
            for _ in range(cfg.period):
                k_r = np.array([sc(cavity.round_trip) for sc in scenarios])
                cavity.set_birefringence(k_r)
                k_sum += k_r
                last = cavity.step()
            blown = ~last.finite
            if blown.any():
                cavity.reset(np.flatnonzero(blown))
            rows['E'][:, j], rows['M'][:, j], rows['O'][:, j] = last.E, last.M, last.O
            rows['converged'][:, j] = last.converged
            rows['K'][:, j] = k_sum / cfg.period
            rows['alpha'][:, j] = applied
            bar.update(1)
        u, v = cavity.fields()
        shards.write_shard(directory, segment, {
            **{k: val[None] for k, val in rows.items()},  # (1, lanes, count, ...)
            'start_period': np.array([start_period]), 'end_u': u, 'end_v': v,
            'end_target': target, 'end_round_trip': np.array(cavity.round_trip),
            'end_rng': np.array(json.dumps(rng.bit_generator.state)),
        })
    bar.close()
    meta = shards.metadata(directory)
    meta.update({'seeds': seeds.tolist(), 'held_out': held_out.tolist(),
                 'wall_seconds_this_run': round(time.monotonic() - started, 1)})
    (directory / 'metadata.json').write_text(json.dumps(meta, indent=2))
    return meta


def load_trajectories(directory: Path) -> dict[str, np.ndarray]:
    """Trajectories as (lanes, periods[, 4]) arrays plus ``held_out`` (lanes,) booleans."""
    directory = Path(directory)
    paths = shards.shard_paths(directory)
    if not paths:
        raise FileNotFoundError(f'no trajectories in {directory}; run `dlmpc-data trajectories`')
    parts: dict[str, list] = {}
    for path in paths:
        with np.load(path) as shard:
            for key in ('E', 'M', 'O', 'K', 'converged', 'alpha'):
                parts.setdefault(key, []).append(shard[key][0])
    data = {k: np.concatenate(v, axis=1) for k, v in parts.items()}
    settings = shards.metadata(directory)['settings']['trajectories']
    data['held_out'] = lane_seeds(TrajectoryConfig(**settings))[1]
    return data


@dataclass(frozen=True)
class TrajectoryTask:
    """One trajectory dataset, generated (or resumed) by a worker into ``directory``."""

    directory: str
    envelope_path: str
    cavity: CavityConfig
    cfg: TrajectoryConfig
    show_progress: bool = False


def trajectory_task(task: TrajectoryTask) -> dict:
    """:func:`generate_trajectories` of the task (the worker writes the shards)."""
    from dlmpc_ros.learning.tables import load_envelope
    return generate_trajectories(Path(task.directory), load_envelope(Path(task.envelope_path)),
                                 task.cavity, task.cfg, task.show_progress)
