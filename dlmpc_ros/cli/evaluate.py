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
import json
import sys
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.control.factory import CONTROLLERS, load_dlmpc, load_estimator, make_baseline
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.core.drift import DEFAULTS, make_scenario, parse_settings
from dlmpc_ros.evaluation.closed_loop import random_initial_angles, run_closed_loop
from dlmpc_ros.evaluation.figures import plot_surrogate, plot_tracking, surrogate_correlation
from dlmpc_ros.evaluation.metrics import run_metrics
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.learning.checkpoint import ModelFileError
from dlmpc_ros.paths import models_dir as default_models_dir

SCENARIOS = ('sinusoidal', 'chirp', 'random_walk', 'steps', 'constant')
#: Evaluation settings of each scenario (K within [-0.3, 0.3]); --scenario-param overrides.
PRESETS: dict[str, dict[str, object]] = {
    'sinusoidal': {'amplitude': 0.25, 'period': 10000.0},
    'chirp': {},
    'random_walk': {'sigma': 0.1, 'correlation_time': 2000.0},
    'steps': {'times': [5000.0, 10000.0, 15000.0], 'values': [0.2, -0.2, 0.1]},
    'constant': {'offset': 0.1},
}
TABLE_KEYS = ('oracle_ratio', 'oracle_controller_ratio', 'locked_fraction',
              'acquisition_round_trips', 'recovery_round_trips_max', 'step_latency_ms_median',
              'step_latency_ms_p99', 'track_estimate_abs_r')


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
        args.settings = {}
        for name in args.scenario:
            settings = {**PRESETS[name], **{k: v for k, v in overrides.items()
                                            if k in DEFAULTS[name]}}
            make_scenario(name, **{**settings, **({'seed': 1} if name == 'random_walk'
                                                  else {})})
            args.settings[name] = settings
        unused = set(overrides) - {k for name in args.scenario for k in DEFAULTS[name]}
        if unused:
            raise ValueError(f'no chosen scenario takes {sorted(unused)}')
        AngleLimits(max_step=args.max_step)
    except ValueError as err:
        p.error(str(err))
    return args


def _setting_strings(settings: dict[str, object]) -> list[str]:
    out = []
    for key, value in settings.items():
        if isinstance(value, (list, tuple)):
            value = ','.join(repr(float(v)) for v in value)
        out.append(f'{key}={value}')
    return out


def run_one(args: argparse.Namespace, scenario_name: str, controller_name: str, seed: int,
            run_dir: Path, dlmpc_overrides: dict | None = None) -> RunRecord:
    """One closed-loop run; ``dlmpc_overrides`` (fast mode only) are DLMPCConfig fields
    that replace the defaults, for ablations (``bench/dlmpc_variants.py``)."""
    if dlmpc_overrides and not args.fast:
        raise ValueError('DL-MPC overrides apply to fast mode only')
    settings = dict(args.settings[scenario_name])
    if scenario_name == 'random_walk':
        settings.setdefault('seed', seed)
    initial = random_initial_angles(seed)
    meta = {'scenario': scenario_name, 'settings': settings, 'controller': controller_name,
            'seed': seed, 'round_trips': args.round_trips, 'period': args.period,
            'mode': 'fast' if args.fast else ('graph-free-run' if args.free_run
                                              else 'graph-lockstep'),
            'initial_angles': initial.tolist(),
            'measurement_noise': args.measurement_noise}
    if not args.fast:
        from dlmpc_ros.evaluation.graph_run import run_graph
        settings_args = _setting_strings(settings)
        return run_graph(run_dir, controller_name, scenario_name, settings_args,
                         args.round_trips, args.period, initial, args.domain_id,
                         lockstep=not args.free_run, models_dir=args.models_dir, meta=meta)
    from tqdm import tqdm

    scenario = make_scenario(scenario_name, **settings)
    limits = AngleLimits(max_step=args.max_step)
    estimator = None
    if controller_name == 'dlmpc':
        from dlmpc_ros.control.dlmpc import DLMPCConfig
        from dlmpc_ros.control.tracking import TrackingConfig
        overrides = dict(dlmpc_overrides or {})
        if isinstance(overrides.get('tracking'), dict):  # from JSON: the tracker's fields
            overrides['tracking'] = TrackingConfig(**overrides['tracking'])
        controller = load_dlmpc(args.models_dir, DLMPCConfig(limits=limits, **overrides))
        estimator = load_estimator(args.models_dir)
    else:
        controller = make_baseline(controller_name, args.models_dir, limits,
                                   initial_k=float(scenario(1)))
    with tqdm(total=args.round_trips, unit='RT', desc=f'{scenario_name}/{controller_name}',
              leave=False, mininterval=1.0) as bar:
        def progress(done: int) -> None:
            bar.update(done - bar.n)
        return run_closed_loop(controller, scenario, args.round_trips, args.period, initial,
                               estimator=estimator, meta=meta, progress=progress,
                               measurement_noise=args.measurement_noise, noise_seed=seed)


def markdown_table(rows: list[dict]) -> str:
    head = ['scenario', 'seed', 'controller', *TABLE_KEYS]
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for row in rows:
        cells = [row['scenario'], str(row['seed']), row['controller']]
        for key in TABLE_KEYS:
            value = row['metrics'].get(key)
            cells.append('-' if value is None else (f'{value:.3f}' if isinstance(value, float)
                                                    else str(value)))
        lines.append('| ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def _summary_line(metrics: dict) -> str:
    def text(key: str, form: str) -> str:
        value = metrics.get(key)
        return 'n/a' if value is None else format(value, form)
    return (f"oracle ratio {text('oracle_ratio', '.3f')}, locked "
            f"{text('locked_fraction', '.3f')}, acquisition "
            f"{text('acquisition_round_trips', 'd')}, latency median "
            f"{text('step_latency_ms_median', '.2f')} ms")


def _measure(record: RunRecord, envelope: dict, run_dir: Path, **extra) -> dict:
    """The run's metrics (plus ``extra``), saved with its record in ``run_dir``."""
    metrics = {**run_metrics(record, envelope), **extra,
               'surrogate_abs_r': surrogate_correlation(record),
               'track_estimate_abs_r': surrogate_correlation(record, tracking=True)}
    record.save(run_dir / 'record.npz')
    (run_dir / 'metrics.json').write_text(json.dumps({**record.meta, **metrics}, indent=2))
    return metrics


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
        metrics = _measure(record, envelope, run_dir)
        runs.append({'scenario': 'bag', 'seed': '-', 'controller': label, 'metrics': metrics,
                     'meta': record.meta})
        if report.rows_with_k:
            plot_tracking({label: record}, envelope, label, f'bag {label}',
                          args.out / 'figures' / f'{label}-tracking.png')
            if np.isfinite(record.surrogate).any():
                plot_surrogate(record, f'bag {label}: VAE surrogate',
                               args.out / 'figures' / f'{label}-surrogate.png')
        print(f'[{i}/{len(args.bag)}] {bag}: {report.rows} round trips, {report.decisions} '
              f'decisions: {_summary_line(metrics)}', flush=True)
    _write_summary(args.out, runs)
    return 0


def add_oracle_controller_ratio(runs: list[dict]) -> None:
    """Add ``oracle_controller_ratio``: mean O over the mean O of the ``oracle``
    controller's run on the same scenario and seed (when the oracle ran too). The envelope
    O*(K) is the point-wise best over branches, which no controller holds; the oracle
    controller's branch-continuous path is the best reached in closed loop."""
    oracle = {(r['scenario'], r['seed']): r['metrics']['mean_O'] for r in runs
              if r['controller'] == 'oracle'}
    for run in runs:
        reference = oracle.get((run['scenario'], run['seed']))
        mean_o = run['metrics'].get('mean_O')
        if reference and mean_o is not None:
            run['metrics']['oracle_controller_ratio'] = mean_o / reference


def seed_summary(runs: list[dict]) -> str:
    """Markdown table of oracle_ratio per scenario (rows) and controller (columns): the
    mean over seeds and, with several seeds, the range."""
    scenarios = list(dict.fromkeys(r['scenario'] for r in runs))
    controllers = list(dict.fromkeys(r['controller'] for r in runs))
    lines = ['| scenario | ' + ' | '.join(controllers) + ' |',
             '|---|' + '---|' * len(controllers)]
    for scenario in scenarios:
        cells = []
        for controller in controllers:
            values = [r['metrics']['oracle_ratio'] for r in runs
                      if r['scenario'] == scenario and r['controller'] == controller
                      and r['metrics'].get('oracle_ratio') is not None]
            if not values:
                cells.append('-')
            elif len(values) == 1:
                cells.append(f'{values[0]:.3f}')
            else:
                cells.append(f'{np.mean(values):.3f} ({min(values):.3f}-{max(values):.3f})')
        lines.append(f'| {scenario} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines) + '\n'


def _write_summary(out: Path, runs: list[dict]) -> None:
    add_oracle_controller_ratio(runs)
    summary: dict = {'runs': runs}
    if len(runs) == 1:
        summary.update(runs[0]['metrics'])
    (out / 'metrics.json').write_text(json.dumps(summary, indent=2))
    seeds = len({r['seed'] for r in runs})
    (out / 'table.md').write_text(
        f'oracle_ratio (mean O / mean O*(K)), mean over {seeds} seed(s)'
        + (' (min-max)' if seeds > 1 else '') + ':\n\n' + seed_summary(runs)
        + '\nEvery run:\n\n' + markdown_table(runs))


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    from dlmpc_ros.learning.baselines import load_baselines
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
    combos = list(itertools.product(args.scenario, args.seed, args.controller))
    for i, (scenario_name, seed, controller_name) in enumerate(combos, 1):
        run_dir = args.out / f'{scenario_name}-s{seed}-{controller_name}'
        started = time.monotonic()
        try:
            record = run_one(args, scenario_name, controller_name, seed, run_dir)
        except (ModelFileError, FileNotFoundError, RuntimeError, ValueError) as err:
            print(f'dlmpc-evaluate: {scenario_name}/{controller_name} failed: {err}',
                  file=sys.stderr)
            return 1
        wall = time.monotonic() - started
        metrics = _measure(record, envelope, run_dir, wall_seconds=round(wall, 2))
        runs.append({'scenario': scenario_name, 'seed': seed, 'controller': controller_name,
                     'metrics': metrics, 'meta': record.meta})
        records[(scenario_name, seed, controller_name)] = record
        print(f'[{i}/{len(combos)}] {scenario_name} seed {seed} {controller_name}: '
              f'{_summary_line(metrics)} ({wall:.0f} s)', flush=True)
    _write_summary(args.out, runs)
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
