"""dlmpc-evaluate: closed-loop runs of controllers on drift scenarios, with metrics,
a markdown table and figures.

Example: ``dlmpc-evaluate --scenario sinusoidal --controller dlmpc --controller fixed_best
--seed 1 --round-trips 20000 --fast --out out/eval`` runs the cross product of scenarios,
controllers and seeds, in one process (``--fast``) or through the real node graph in
lockstep (default), and writes ``OUT/metrics.json``, ``OUT/table.md``, ``OUT/figures/``
and one folder per run (``record.npz``, ``metrics.json``).

``dlmpc-evaluate --bag DIR [--bag DIR ...] --out OUT`` does the same for runs recorded
with ``bringup --record`` (or the recorder node): the same metrics, table and figures as
a live run. A bag without ``/laser/sim_truth`` (a real laser) gets the metrics that need
no true K.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dlmpc_ros.control.factory import CONTROLLERS
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.core.drift import DEFAULTS, parse_settings
from dlmpc_ros.evaluation.figures import plot_surrogate, plot_tracking
from dlmpc_ros.evaluation.presets import SCENARIOS, preset_settings
from dlmpc_ros.evaluation.report import measure, summary_line, write_summary
from dlmpc_ros.evaluation.runs import RunSpec, run_spec
from dlmpc_ros.learning.checkpoint import ModelFileError
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.paths import models_dir as default_models_dir


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='dlmpc-evaluate', description=__doc__.split('\n\n')[0])
    p.add_argument('--scenario', action='append', choices=SCENARIOS,
                   help='drift scenario, repeatable (default: sinusoidal)')
    p.add_argument('--scenario-param', action='append', default=[], metavar='KEY=VALUE',
                   help='scenario setting, repeatable; applies to every scenario that takes it')
    p.add_argument('--controller', action='append', choices=CONTROLLERS,
                   help='controller, repeatable (default: dlmpc)')
    p.add_argument('--seed', action='append', type=int,
                   help='seed of the random initial angles and of random_walk, repeatable '
                        '(default: 1; training used 1000+ and 5000+)')
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--period', type=int, default=10, help='control period P [round trips]')
    p.add_argument('--max-step', type=float, default=0.25,
                   help='servo speed: largest angle change per period [rad]')
    p.add_argument('--measurement-noise', type=float, default=0.0, metavar='SIGMA',
                   help='fast mode: relative Gaussian noise on the E and M the estimator '
                        'and controller see (the record keeps the true values)')
    p.add_argument('--fast', action='store_true',
                   help='run the core objects in one process instead of the node graph')
    p.add_argument('--free-run', action='store_true',
                   help='graph mode without lockstep (depends on machine load)')
    p.add_argument('--models-dir', type=Path, help='model files (default: installed models/)')
    p.add_argument('--domain-id', type=int, default=88, help='ROS domain of graph runs')
    p.add_argument('--bag', action='append', type=Path, metavar='DIR',
                   help='evaluate a recorded rosbag2 bag instead of running, repeatable')
    p.add_argument('--out', type=Path, required=True, help='output directory')
    args = p.parse_args(argv)
    args.models_dir = args.models_dir or default_models_dir()
    if args.measurement_noise and not args.fast:
        p.error('--measurement-noise applies to --fast runs (a graph run measures the '
                'laser node as it is)')
    if not 0 <= args.measurement_noise < 1:
        p.error('--measurement-noise must be in [0, 1)')
    if args.bag and (args.scenario or args.controller or args.seed or args.fast):
        p.error('--bag evaluates recorded runs; it takes no --scenario, --controller, '
                '--seed or --fast')
    if args.bag:
        return args
    args.scenario = args.scenario or ['sinusoidal']
    args.controller = args.controller or ['dlmpc']
    args.seed = args.seed or [1]
    if args.round_trips < 1 or args.period < 1:
        p.error('--round-trips and --period must be >= 1')
    try:
        overrides = parse_settings(args.scenario_param)
        args.settings = {name: preset_settings(name, overrides) for name in args.scenario}
        unused = set(overrides) - {k for name in args.scenario for k in DEFAULTS[name]}
        if unused:
            raise ValueError(f'no chosen scenario takes {sorted(unused)}')
        AngleLimits(max_step=args.max_step)
    except ValueError as err:
        p.error(str(err))
    return args


def run_specs(args: argparse.Namespace) -> list[RunSpec]:
    """The runs the arguments ask for: scenarios x seeds x controllers."""
    mode = 'fast' if args.fast else ('graph-free-run' if args.free_run else 'graph-lockstep')
    return [RunSpec(scenario, seed, controller, args.settings[scenario], args.round_trips,
                    args.period, args.max_step, args.measurement_noise, mode)
            for scenario, seed, controller in itertools.product(args.scenario, args.seed,
                                                                args.controller)]


def evaluate_bags(args: argparse.Namespace, envelope: dict) -> int:
    """Metrics, table and figures of recorded bags (one folder per bag under OUT)."""
    from dlmpc_ros.evaluation.graph_run import record_from_csv
    from dlmpc_ros.recording import BagError
    from dlmpc_ros.recording.export import bag_to_csv

    runs = []
    names = [bag.resolve().name for bag in args.bag]
    for i, bag in enumerate(args.bag, 1):
        label = names[i - 1] if names.count(names[i - 1]) == 1 else f'{names[i - 1]}-{i}'
        run_dir = args.out / label
        try:
            report = bag_to_csv(bag, run_dir / 'run.csv')
            record = record_from_csv(report.run_csv, {'source': 'bag', 'bag': str(bag)})
        except (BagError, OSError, ValueError) as err:
            print(f'dlmpc-evaluate: {bag}: {err}', file=sys.stderr)
            return 1
        metrics = measure(record, envelope, run_dir)
        runs.append({'scenario': 'bag', 'seed': '-', 'controller': label, 'metrics': metrics,
                     'meta': record.meta})
        if report.rows_with_k:
            plot_tracking({label: record}, envelope, label, f'bag {label}',
                          args.out / 'figures' / f'{label}-tracking.png')
            if np.isfinite(record.surrogate).any():
                plot_surrogate(record, f'bag {label}: VAE surrogate',
                               args.out / 'figures' / f'{label}-surrogate.png')
        print(f'[{i}/{len(args.bag)}] {bag}: {report.rows} round trips, {report.decisions} '
              f'decisions: {summary_line(metrics)}', flush=True)
    write_summary(args.out, runs)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        envelope = load_baselines(args.models_dir / 'oracle.npz')
    except (ModelFileError, FileNotFoundError) as err:
        print(f'dlmpc-evaluate: {err}', file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    if args.bag:
        code = evaluate_bags(args, envelope)
        if code == 0:
            print(f'dlmpc-evaluate: wrote {args.out}/metrics.json, table.md and figures/')
        return code
    runs, records = [], {}
    specs = run_specs(args)
    for i, spec in enumerate(specs, 1):
        run_dir = args.out / f'{spec.scenario}-s{spec.seed}-{spec.controller}'
        started = time.monotonic()
        try:
            with tqdm(total=spec.round_trips, unit='RT', desc=f'{spec.scenario}/'
                      f'{spec.controller}', leave=False, mininterval=1.0,
                      disable=not args.fast) as bar:
                record = run_spec(spec, args.models_dir, run_dir, args.domain_id,
                                  progress=lambda done: bar.update(done - bar.n))
        except (ModelFileError, FileNotFoundError, RuntimeError, ValueError) as err:
            print(f'dlmpc-evaluate: {spec.scenario}/{spec.controller} failed: {err}',
                  file=sys.stderr)
            return 1
        wall = time.monotonic() - started
        metrics = measure(record, envelope, run_dir, wall_seconds=round(wall, 2))
        runs.append({'scenario': spec.scenario, 'seed': spec.seed,
                     'controller': spec.controller, 'metrics': metrics, 'meta': record.meta})
        records[(spec.scenario, spec.seed, spec.controller)] = record
        print(f'[{i}/{len(specs)}] {spec.scenario} seed {spec.seed} {spec.controller}: '
              f'{summary_line(metrics)} ({wall:.0f} s)', flush=True)
    write_summary(args.out, runs)
    for scenario_name, seed in itertools.product(args.scenario, args.seed):
        group = {c: records[(scenario_name, seed, c)] for c in args.controller}
        shown = 'dlmpc' if 'dlmpc' in group else args.controller[0]
        plot_tracking(group, envelope, shown, f'{scenario_name}, seed {seed}',
                      args.out / 'figures' / f'{scenario_name}-s{seed}-tracking.png')
        if 'dlmpc' in group:
            plot_surrogate(group['dlmpc'], f'{scenario_name}, seed {seed}',
                           args.out / 'figures' / f'{scenario_name}-s{seed}-surrogate.png')
    print(f'dlmpc-evaluate: wrote {args.out}/metrics.json, table.md and figures/')
    return 0


if __name__ == '__main__':
    sys.exit(main())
