"""dlmpc-data: generate the training datasets (resumable, with progress bars).

``dlmpc-data all`` runs, in order: ``sweep`` (steady states over K x angle sets),
``oracle`` (the envelope O*(K) and its angles) and ``trajectories`` (drifting-K runs
with exploring angles, one row per control period; then ``trajectories_extra``, more
training lanes with their own seeds that only the predictor trains on). Re-running
resumes from the shards already written. ``--quick`` uses tiny settings (for tests and
smoke runs).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.learning.tables import load_envelope
from dlmpc_ros.training.envelope import OracleConfig, generate_oracle
from dlmpc_ros.training.sweep import SweepConfig, generate_sweep
from dlmpc_ros.training.trajectories import TrajectoryConfig, generate_trajectories
from dlmpc_ros.training.workspace import Workspace

QUICK_SWEEP = SweepConfig(sobol_sets=32, refine_sets=16, k_points=7, batch=48,
                          chains_per_shard=16, first_cap=200, cap=60)
QUICK_ORACLE = OracleConfig(candidates=2, first_step=0.08, min_step=0.04, max_iterations=3,
                            cap=100, check_directions=2)
QUICK_TRAJECTORIES = TrajectoryConfig(train_lasers=6, test_lasers=3, round_trips=1500,
                                      segment_periods=50)
#: Training lanes of ``trajectories_extra`` (no held-out lanes; its seed is --seed + 1).
EXTRA_LANES, QUICK_EXTRA_LANES = 128, 4


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='dlmpc-data', description=__doc__.split('\n\n')[0])
    p.add_argument('stage', choices=('all', 'sweep', 'oracle', 'trajectories'))
    p.add_argument('--data-dir', type=Path, default=Path('data'))
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--quick', action='store_true', help='tiny settings for tests')
    p.add_argument('--no-progress', action='store_true')
    args = p.parse_args(argv)
    ws = Workspace(data_dir=args.data_dir)
    cavity = CavityConfig()
    show = not args.no_progress
    report = {}
    started = time.monotonic()
    try:
        if args.stage in ('all', 'sweep'):
            cfg = QUICK_SWEEP if args.quick else SweepConfig()
            cfg = SweepConfig(**{**cfg.to_dict(), 'seed': args.seed})
            report['sweep'] = generate_sweep(ws.sweep, cfg, cavity, show)
        if args.stage in ('all', 'oracle'):
            cfg = QUICK_ORACLE if args.quick else OracleConfig()
            report['oracle'] = generate_oracle(ws.sweep, ws.oracle, cavity, cfg, show)
        if args.stage in ('all', 'trajectories'):
            cfg = QUICK_TRAJECTORIES if args.quick else TrajectoryConfig()
            cfg = TrajectoryConfig(**{**cfg.to_dict(), 'seed': args.seed})
            envelope = load_envelope(ws.oracle)
            report['trajectories'] = generate_trajectories(
                ws.trajectories, envelope, cavity, cfg, show)
            extra = TrajectoryConfig(**{
                **cfg.to_dict(), 'test_lasers': 0, 'seed': args.seed + 1,
                'train_lasers': QUICK_EXTRA_LANES if args.quick else EXTRA_LANES})
            report['trajectories_extra'] = generate_trajectories(
                ws.extra_trajectories, envelope, cavity, extra, show)
    except (FileNotFoundError, ValueError) as err:
        print(f'dlmpc-data: {err}', file=sys.stderr)
        return 2
    for stage, meta in report.items():
        meta = {k: v for k, v in meta.items() if k not in ('settings', 'seeds', 'held_out')}
        print(f'{stage}: {json.dumps(meta)}')
    print(f'dlmpc-data: done in {time.monotonic() - started:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
