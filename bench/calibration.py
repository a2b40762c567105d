"""What calibration from a bag buys, and after how many round trips of exploring.

For each plant: records the exploring DL-MPC through the real node graph (``bringup
--controller explore --lockstep --record``) on a random walk of K with its own seed (none
of the evaluation's), then for each budget runs ``dlmpc-train adapt --bag DIR
--round-trips BUDGET`` and measures the calibrated models with ``dlmpc-evaluate --fast
--models-dir`` on the evaluation's drifts and seeds, beside the shipped models on the
same runs::

    python bench/calibration.py --plant-family 101 --plant-family 102 \\
        --budget 2000 --budget 5000 --budget 20000 --out bench/results/calibration

Writes ``OUT/calibration.json`` and ``OUT/calibration.md`` (mean O / O* per plant and
budget, 0 being the shipped models, and the |r| of the estimator's surrogate with K while
the tracker tracked). ``--laser-estimator``: adapt also learns the laser's own estimator.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def run(cmd: list[str], **kw) -> None:
    print('+', ' '.join(cmd), flush=True)
    subprocess.run(cmd, check=True, **kw)


def evaluate(plant: int, models: Path, out: Path, seeds: list[int], workers: int) -> dict:
    """Mean oracle ratio per scenario of the DL-MPC with ``models`` on ``plant``."""
    run([str(BIN / 'dlmpc-evaluate'), '--fast', '--round-trips', '20000', '--plant-family',
         str(plant), '--scenario', 'sinusoidal', '--scenario', 'random_walk',
         *[a for s in seeds for a in ('--seed', str(s))], '--controller', 'dlmpc',
         '--models-dir', str(models), '--workers', str(workers), '--out', str(out)])
    runs = json.loads((out / 'metrics.json').read_text())['runs']
    row = {scenario: float(np.mean([r['metrics']['oracle_ratio'] for r in runs
                                    if r['scenario'] == scenario]))
           for scenario in ('sinusoidal', 'random_walk')}
    # |r| of the estimator's own surrogate with K while the tracker tracked (K: scores only)
    row['estimator_abs_r'] = [r['metrics'].get('estimator_abs_r') for r in runs]
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--plant-family', type=int, action='append', required=True)
    p.add_argument('--budget', type=int, action='append', required=True,
                   help='round trips of the exploring run the calibration may use')
    p.add_argument('--record-round-trips', type=int, default=0,
                   help='length of the exploring run (default: the largest budget)')
    p.add_argument('--walk-seed', type=int, default=77)
    p.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    p.add_argument('--workers', type=int, default=2)
    p.add_argument('--domain-id', type=int, default=93)
    p.add_argument('--laser-estimator', action='store_true',
                   help="adapt also learns the laser's own estimator and map")
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)
    length = args.record_round_trips or max(args.budget)
    results = {'settings': vars(args) | {'out': str(args.out)}, 'plants': {}}
    env = {**os.environ, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    for plant in args.plant_family:
        work = args.out / f'family-{plant}'
        bag = work / 'explore-bag'
        if not bag.exists():
            started = time.monotonic()
            run([str(BIN / 'bringup'), '--controller', 'explore', '--lockstep',
                 '--plant-family', str(plant), '--scenario', 'random_walk', '--scenario-param',
                 f'seed={args.walk_seed}', '--round-trips', str(length), '--record', str(bag),
                 '--domain-id', str(args.domain_id), '--log-dir', str(work / 'logs')], env=env)
            print(f'recorded {length} round trips in {time.monotonic() - started:.0f} s')
        rows = {0: evaluate(plant, ROOT / 'models', work / 'shipped', args.seeds,
                            args.workers)}
        for budget in sorted(args.budget):
            models = work / f'models-{budget}'
            run([str(BIN / 'dlmpc-train'), 'adapt', '--bag', str(bag), '--round-trips',
                 str(budget), '--models-dir', str(ROOT / 'models'), '--out', str(models),
                 '--no-progress', *(['--laser-estimator'] if args.laser_estimator else [])])
            rows[budget] = evaluate(plant, models, work / f'eval-{budget}', args.seeds,
                                    args.workers)
            rows[budget]['adapt'] = json.loads((models / 'adapt.json').read_text())
        results['plants'][plant] = rows
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'calibration.json').write_text(json.dumps(results, indent=1, default=str))
    lines = ['| plant | budget [round trips] | sinusoidal | random_walk | pairs fit / held out '
             '| held-out RMSE shipped -> corrected | correction (a, b, c) | prior knots '
             '| estimator \\|r\\| (min-max) |', '|---|---|---|---|---|---|---|---|---|']
    for plant, rows in results['plants'].items():
        for budget, row in rows.items():
            a = row.get('adapt')
            extra = ('- | - | - | -' if a is None else
                     f"{a['pairs']} / {a['held_out_pairs']} | {a['held_out_rmse_before']:.3f} -> "
                     f"{a['held_out_rmse_corrected']:.3f} | "
                     f"{', '.join(f'{c:.4f}' for c in a['correction'])} | "
                     f"{a['prior_knots_set']}")
            r = [v for v in row['estimator_abs_r'] if v is not None]
            spread = f'{min(r):.2f}-{max(r):.2f}' if r else '-'
            lines.append(f"| family-{plant} | {budget or 'shipped models'} | "
                         f"{row['sinusoidal']:.3f} | {row['random_walk']:.3f} | {extra} | "
                         f"{spread} |")
    (args.out / 'calibration.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
