"""dlmpc-data: generate the training datasets (resumable, with progress).

``dlmpc-data all`` runs, in order: ``sweep`` (steady states over K x angle sets),
``oracle`` (the envelope O*(K) and its angles) and ``trajectories`` (drifting-K runs
with exploring angles, one row per control period; then ``trajectories_extra``, more
training lanes with their own seeds that only the predictor trains on). Re-running
resumes from the shards already written. ``--quick`` uses tiny settings (for tests and
smoke runs). The independent parts (the sweep's shards, the envelope's K points, the two
trajectory sets) run as tasks on ``--workers`` local Dask workers or on the cluster at
``--scheduler``, with the same data as one worker (``--workers 1``, in this process).

``dlmpc-data oracle --plant KEY=VALUE`` (or ``--plant-family SEED``) computes the envelope
of a plant instead (:func:`dlmpc_ros.training.envelope.plant_envelope`: from the nominal
tables of ``--models-dir``, minutes) and caches it by the plant's fingerprint.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.plants import PlantFamily, parse_plant, plant_fingerprint
from dlmpc_ros.scaleout import TaskFailure, default_workers, run_tasks
from dlmpc_ros.training.envelope import (OracleConfig, cached_plant_envelope, draw_plant,
                                         generate_oracle)
from dlmpc_ros.training.sweep import SweepConfig, generate_sweep
from dlmpc_ros.training.trajectories import TrajectoryConfig, TrajectoryTask, trajectory_task
from dlmpc_ros.training.workspace import Workspace

QUICK_SWEEP = SweepConfig(sobol_sets=32, refine_sets=16, k_points=7, batch=48,
                          chains_per_shard=16, first_cap=200, cap=60)
QUICK_ORACLE = OracleConfig(candidates=2, first_step=0.08, min_step=0.04, max_iterations=3,
                            cap=100, check_directions=2)
QUICK_TRAJECTORIES = TrajectoryConfig(train_lasers=6, test_lasers=3, round_trips=1500,
                                      segment_periods=50)
#: Training lanes of ``trajectories_extra`` (no held-out lanes; its seed is --seed + 1).
EXTRA_LANES, QUICK_EXTRA_LANES = 128, 4


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='dlmpc-data', description=__doc__.split('\n\n')[0])
    p.add_argument('stage', choices=('all', 'sweep', 'oracle', 'trajectories'))
    p.add_argument('--data-dir', type=Path, default=Path('data'))
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--quick', action='store_true', help='tiny settings for tests')
    p.add_argument('--no-progress', action='store_true')
    p.add_argument('--workers', type=int, default=default_workers(),
                   help='local Dask workers (1: in this process; default: the cores, '
                        '%(default)s)')
    p.add_argument('--scheduler', metavar='ADDRESS',
                   help='run the tasks on the Dask cluster at ADDRESS (its workers must '
                        'share --data-dir)')
    p.add_argument('--plant', action='append', default=[], metavar='KEY=VALUE',
                   help='oracle: the envelope of this plant (physical parameters), cached')
    p.add_argument('--plant-family', type=int, metavar='SEED',
                   help='oracle: the envelope of plant SEED of the family, cached')
    p.add_argument('--models-dir', type=Path,
                   help='oracle of a plant: the nominal tables it starts from '
                        '(default: the installed models/)')
    p.add_argument('--cache', type=Path, help='cache of plant envelopes (default: '
                                               '~/.cache/dlmpc_ros)')
    args = p.parse_args(argv)
    if args.workers < 1:
        p.error('--workers must be >= 1')
    if (args.plant or args.plant_family is not None) and args.stage != 'oracle':
        p.error('--plant and --plant-family go with the oracle stage')
    if args.plant and args.plant_family is not None:
        p.error('give --plant or --plant-family, not both')
    try:
        args.cavity = parse_plant(args.plant) if args.plant else None
    except ValueError as err:
        p.error(str(err))
    return args


def plant_oracle(args: argparse.Namespace) -> dict:
    """The cached envelope of the plant the arguments name."""
    from dlmpc_ros.learning.tables import load_baselines
    from dlmpc_ros.paths import models_dir
    tables = load_baselines(models_dir(args.models_dir or '') / 'oracle.npz')
    cavity = args.cavity
    if cavity is None:
        cavity, attempt = draw_plant(PlantFamily(), args.plant_family, tables,
                                     directory=args.cache)
        print(f'plant family seed {args.plant_family}: draw {attempt}', flush=True)

    def progress(iteration, mean_o, active):
        if not args.no_progress:
            print(f'plant oracle: iteration {iteration:2d}  mean O* {mean_o:.4f}  K points '
                  f'still moving {active}', flush=True)

    started = time.monotonic()
    env = cached_plant_envelope(cavity, tables, directory=args.cache, progress=progress)
    return {'plant_fingerprint': plant_fingerprint(cavity), 'k_points': int(env['K'].size),
            'mean_O_star': float(np.mean(env['O_star'])),
            'mode_locks': bool(env['mode_locks']),
            'wall_seconds': round(time.monotonic() - started, 1)}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    ws = Workspace(data_dir=args.data_dir)
    cavity = CavityConfig()
    show = not args.no_progress
    parallel = {'workers': args.workers, 'scheduler': args.scheduler}
    report = {}
    started = time.monotonic()
    try:
        if args.cavity is not None or args.plant_family is not None:
            report['plant oracle'] = plant_oracle(args)
        else:
            if args.stage in ('all', 'sweep'):
                cfg = QUICK_SWEEP if args.quick else SweepConfig()
                cfg = SweepConfig(**{**cfg.to_dict(), 'seed': args.seed})
                report['sweep'] = generate_sweep(ws.sweep, cfg, cavity, show, **parallel)
            if args.stage in ('all', 'oracle'):
                cfg = QUICK_ORACLE if args.quick else OracleConfig()
                report['oracle'] = generate_oracle(ws.sweep, ws.oracle, cavity, cfg, show,
                                                   **parallel)
            if args.stage in ('all', 'trajectories'):
                report.update(trajectories(args, ws, cavity, show))
    except (FileNotFoundError, ValueError, RuntimeError) as err:
        print(f'dlmpc-data: {err}', file=sys.stderr)
        return 2
    for stage, meta in report.items():
        meta = {k: v for k, v in meta.items() if k not in ('settings', 'seeds', 'held_out')}
        print(f'{stage}: {json.dumps(meta)}')
    print(f'dlmpc-data: done in {time.monotonic() - started:.0f} s')
    return 0


def trajectories(args: argparse.Namespace, ws: Workspace, cavity: CavityConfig,
                 show: bool) -> dict:
    """The trajectories and the extra training lanes, as two tasks."""
    cfg = QUICK_TRAJECTORIES if args.quick else TrajectoryConfig()
    cfg = TrajectoryConfig(**{**cfg.to_dict(), 'seed': args.seed})
    extra = TrajectoryConfig(**{
        **cfg.to_dict(), 'test_lasers': 0, 'seed': args.seed + 1,
        'train_lasers': QUICK_EXTRA_LANES if args.quick else EXTRA_LANES})
    serial = args.workers == 1 and args.scheduler is None
    tasks = [TrajectoryTask(str(ws.trajectories), str(ws.oracle), cavity, cfg, show and serial),
             TrajectoryTask(str(ws.extra_trajectories), str(ws.oracle), cavity, extra,
                            show and serial)]
    results = run_tasks(trajectory_task, tasks, args.workers, args.scheduler,
                        desc='trajectory sets', show_progress=show)
    failed = [r for r in results if isinstance(r, TaskFailure)]
    if failed:
        raise RuntimeError('; '.join(str(f) for f in failed))
    return {'trajectories': results[0], 'trajectories_extra': results[1]}


if __name__ == '__main__':
    sys.exit(main())
