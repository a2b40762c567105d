"""What a controller that knows the true K and the plant's own best angles holds (issue 32).

The plant's oracle sets, every control period, the angles of the plant's envelope at the K
grid point nearest the true K (:class:`~dlmpc_ros.control.baselines.OracleController` with
the plant's envelope; ``dlmpc-evaluate --controller oracle`` uses the nominal cavity's
tables), through the same servo limits and bench emulation as every controller. No
controller can read K, so this is no controller's target; it shows what the envelope, a
steady state, leaves out: the round trips a pulse needs to form again where the best
angles jump (each step of the stress suite's ``steps`` moves K by 0.6). Its jumps between
the envelope's points, which may lie on different branches, can lose a pulse that a
continuous path would keep, so on the drifts it is no upper bound either.

    python bench/plant_oracle.py --nominal --plant-family 1 ... --plant-family 8 \\
        --condition steps-ideal --condition steps-servo3 ... --seeds 1 --workers 2 \\
        --out bench/results/plant_oracle.json

Writes the runs (plant, condition, seed, oracle ratio, locked fraction) as JSON and a table
of the mean ratio per condition beside it (``.md``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.paths import models_dir as installed_models
from dlmpc_ros.scaleout import TaskFailure, run_tasks

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dlmpc_variants import plant_and_envelope  # noqa: E402  (a bench script beside this one)


@dataclass(frozen=True)
class OracleRun:
    """One run of the plant's oracle."""

    plant: str       # 'nominal' or a family seed
    condition: str   # a stress suite condition's name
    seed: int
    models_dir: str


def run_one(job: OracleRun) -> dict:
    """One closed-loop run of the plant's oracle, with its metrics."""
    from dlmpc_ros.control.baselines import OracleController
    from dlmpc_ros.control.step import AngleLimits
    from dlmpc_ros.evaluation.metrics import run_metrics
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.evaluation.suites import stress_conditions

    models = Path(job.models_dir)
    plant, envelope = plant_and_envelope(job.plant, models)
    c = stress_conditions()[job.condition]
    spec = RunSpec(c.scenario, job.seed, 'oracle', settings=c.settings, plant=plant,
                   bench=c.bench, condition=job.condition)
    oracle = OracleController(envelope['K'], envelope['angles'],
                              AngleLimits(max_step=spec.max_step))
    metrics = run_metrics(run_fast(spec, models, oracle), envelope)
    return {'plant': job.plant, 'condition': job.condition, 'seed': job.seed,
            **{k: metrics[k] for k in ('oracle_ratio', 'locked_fraction', 'mean_O')}}


def table(runs: list[dict]) -> str:
    """Mean oracle ratio per condition (over plants and seeds), with its range."""
    by = defaultdict(list)
    for r in runs:
        by[r['condition']].append(r['oracle_ratio'])
    lines = ['| condition | runs | plant oracle, mean ratio | lowest | highest |',
             '|---|---|---|---|---|']
    lines += [f'| {c} | {len(v)} | {np.mean(v):.3f} | {min(v):.3f} | {max(v):.3f} |'
              for c, v in sorted(by.items())]
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--nominal', action='store_true', help='the nominal cavity')
    p.add_argument('--plant-family', type=int, action='append', default=[],
                   help='a family seed, repeatable')
    p.add_argument('--condition', action='append', required=True,
                   help='a stress suite condition, repeatable (docs/evaluation.md)')
    p.add_argument('--seeds', type=int, nargs='+', default=[1])
    p.add_argument('--workers', type=int, default=1)
    p.add_argument('--models-dir', type=Path, default=None)
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)
    from dlmpc_ros.evaluation.suites import stress_conditions
    unknown = sorted(set(args.condition) - set(stress_conditions()))
    if unknown:
        p.error(f'unknown condition(s) {unknown}; one of {sorted(stress_conditions())}')
    models = args.models_dir or installed_models()
    plants = (['nominal'] if args.nominal or not args.plant_family else []) + \
        [str(s) for s in args.plant_family]
    for plant in plants:  # draws and envelopes once, here, before the runs share them
        plant_and_envelope(plant, models)
    jobs = [OracleRun(plant, c, seed, str(models)) for plant in plants
            for c in args.condition for seed in args.seeds]
    results = run_tasks(run_one, jobs, args.workers, desc='plant oracle runs')
    failed = [str(r) for r in results if isinstance(r, TaskFailure)]
    runs = [r for r in results if not isinstance(r, TaskFailure)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'plants': plants, 'conditions': args.condition,
                                    'seeds': args.seeds, 'failed': failed, 'runs': runs},
                                   indent=1) + '\n')
    args.out.with_suffix('.md').write_text(table(runs))
    print(table(runs))
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
