"""dlmpc-evaluate: closed-loop runs of controllers on drift scenarios and plants, with
metrics, markdown tables and figures; and the auto-mode-locking benchmark.

Example: ``dlmpc-evaluate --scenario sinusoidal --controller dlmpc --controller fixed_best
--seed 1 --round-trips 20000 --fast --out out/eval`` runs the cross product of scenarios,
controllers and seeds, in one process per run (``--fast``, on Dask workers:
``--workers N``, ``--scheduler ADDRESS``) or through the real node graph in lockstep
(default, one run at a time), and writes ``OUT/metrics.json``, ``OUT/table.md``,
``OUT/figures/`` and one folder per run (``record.npz``, ``metrics.json``).

Plants (:mod:`dlmpc_ros.core.plants`): ``--plant KEY=VALUE`` (repeatable) sets the
simulated cavity's physical parameters, ``--plant-family SEED`` (repeatable) draws
plants of the documented family; each plant's envelope O*(K) divides its runs
(computed once and cached, minutes each). With several plants the runs go to
``OUT/<plant>/``. No plant parameter reaches a controller.

``--benchmark lock --starts N`` scores auto-mode-locking instead: N cold starts from
random angles and a noise field, K drawn per start, ``--budget`` round trips each
(:mod:`dlmpc_ros.evaluation.lock_benchmark`); writes ``OUT/lock.json`` and
``OUT/lock.png``. ``--budget`` given several times is a budget sweep: every start runs
once at the largest, each smaller one is scored from its time to lock, and the smallest
is the headline.

``--suite stress`` runs the stress suite instead of ``--scenario`` (fast mode): 16
conditions (four drifts over the whole K range, each on ideal servos, the ``servo-3`` and
``servo-6`` benches and with 1 % detector noise, :mod:`dlmpc_ros.evaluation.suites`),
seeds 1-3 and every built-in controller unless ``--seed`` / ``--controller`` say
otherwise; besides the usual outputs it writes ``OUT/stress.md`` and ``OUT/stress.json``
(plant x condition x controller). Its lock part is ``--benchmark lock --lock-k 0.3`` and
``--lock-k -0.3``.

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
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros.control.factory import CONTROLLERS
from dlmpc_ros.control.plugins import ControllerSpecError, build, label
from dlmpc_ros.control.step import (MEASUREMENT_ROUND_TRIPS, SETTLE_TIMEOUT, SETTLE_TOLERANCE,
                                    AngleLimits)
from dlmpc_ros.core.bench import BENCH_FIELDS, BENCH_PRESETS, parse_bench
from dlmpc_ros.core.drift import DEFAULTS, parse_settings
from dlmpc_ros.evaluation.figures import plot_surrogate, plot_tracking
from dlmpc_ros.evaluation.presets import SCENARIOS, preset_settings
from dlmpc_ros.core.plants import PHYSICS_FIELDS, parse_plant, plant_parameters
from dlmpc_ros.evaluation.lock_benchmark import (DRIFTS, LockSpec, LockTask, plot_lock_times,
                                                 run_starts, sweep_metrics)
from dlmpc_ros.evaluation.report import (lock_table, measure, summary_line, write_plant_table,
                                         write_summary)
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.evaluation.runs import RunSpec, RunTask, run_spec, run_task
from dlmpc_ros.evaluation.suites import (STRESS_LOCK_K, SUITE_CONTROLLERS, SUITE_SEEDS, SUITES,
                                         over_envelope, over_envelope_warning, write_suite)
from dlmpc_ros.learning.model_files import ModelFileError
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.paths import models_dir as default_models_dir
from dlmpc_ros.scaleout import TaskFailure, default_workers, run_tasks
from dlmpc_ros.training.envelope import PlantTask, draw_task, envelope_task


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='dlmpc-evaluate', description=__doc__.split('\n\n')[0])
    p.add_argument('--scenario', action='append', choices=SCENARIOS,
                   help='drift scenario, repeatable (default: sinusoidal)')
    p.add_argument('--suite', choices=tuple(SUITES),
                   help='run a benchmark suite of conditions (scenario, settings and bench) '
                        'instead of --scenario, in fast mode: stress = the whole K range on '
                        'ideal and slow servos and with 1 %% detector noise, seeds 1-3 and '
                        'every built-in controller by default (docs/evaluation.md); writes '
                        'OUT/stress.md and OUT/stress.json')
    p.add_argument('--condition', action='append', default=[], metavar='NAME',
                   help='with --suite: run only this condition, repeatable (e.g. '
                        'sin6k-servo3; the names are listed in docs/evaluation.md)')
    p.add_argument('--scenario-param', action='append', default=[], metavar='KEY=VALUE',
                   help='scenario setting, repeatable; applies to every scenario that takes it')
    p.add_argument('--controller', action='append', metavar='NAME|MODULE:FACTORY',
                   help=f'controller, repeatable (default: dlmpc): one of '
                        f'{", ".join(CONTROLLERS)}, another registered name, or '
                        'package.module:factory (docs/controllers.md)')
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
    p.add_argument('--measurement-round-trips', type=int, default=MEASUREMENT_ROUND_TRIPS,
                   metavar='N',
                   help="the estimator and controller read each period's E and M as the "
                        'mean of its last N round trips at its angles (default: %(default)s)')
    p.add_argument('--bench', action='append', default=[], metavar='PRESET|KEY=VALUE',
                   help='emulate the lab bench (servos, encoders, detectors), repeatable: a '
                        f'preset ({", ".join(BENCH_PRESETS)}) or a setting '
                        f'({", ".join(BENCH_FIELDS)}); docs/nodes.md')
    p.add_argument('--settle-tolerance', type=float, default=SETTLE_TOLERANCE, metavar='RAD',
                   help='fast runs: a state counts for a decision once its reported angles '
                        'are this close to the command (default: %(default)s)')
    p.add_argument('--settle-timeout', type=int, default=SETTLE_TIMEOUT, metavar='N',
                   help='fast runs: round trips after a decision by which the next is made '
                        'even if the servos have not settled (default: %(default)s)')
    p.add_argument('--fast', action='store_true',
                   help='run the core objects in one process instead of the node graph')
    p.add_argument('--free-run', action='store_true',
                   help='graph mode without lockstep (depends on machine load)')
    p.add_argument('--models-dir', type=Path, help='model files (default: installed models/)')
    p.add_argument('--domain-id', type=int, default=88, help='ROS domain of graph runs')
    p.add_argument('--bag', action='append', type=Path, metavar='DIR',
                   help='evaluate a recorded rosbag2 bag instead of running, repeatable')
    p.add_argument('--plant', action='append', default=[], metavar='KEY=VALUE',
                   help=f'a physical parameter of the simulated cavity, repeatable (one of '
                        f'{", ".join(PHYSICS_FIELDS)}); the simulator and the evaluation '
                        'see it, no controller does')
    p.add_argument('--plant-family', action='append', type=int, default=[], metavar='SEED',
                   help='a plant drawn from the family of core/plants.py, repeatable '
                        '(development plants: 1-8 with --nominal; held-out: 101-108, for '
                        'reports only)')
    p.add_argument('--nominal', action='store_true',
                   help='also run the nominal cavity (the default without plant options; '
                        'a development plant)')
    p.add_argument('--benchmark', choices=('drift', 'lock'), default='drift',
                   help='drift: the scenarios (default); lock: the auto-mode-locking '
                        'benchmark of cold starts')
    p.add_argument('--starts', type=int, default=100, help='lock: cold starts per plant')
    p.add_argument('--budget', type=int, action='append', metavar='N',
                   help='lock: round trips per start (default: 1000); repeatable: a budget '
                        'sweep, run once at the largest, each scored from the times to lock, '
                        'the smallest as the headline (OUT/lock.md, a log-axis lock.png)'),
    p.add_argument('--lock-drift', choices=DRIFTS, default='held',
                   help='lock: K held at its draw, or drifting slowly around it')
    p.add_argument('--lock-k', type=float, metavar='K',
                   help='lock: K of every start (its drift starts there) instead of a '
                        f'uniform draw in [-0.3, 0.3]; the stress suite runs '
                        f'{" and ".join(f"{k:+g}" for k in STRESS_LOCK_K)}')
    p.add_argument('--workers', type=int, default=default_workers(),
                   help='fast runs, plant draws and envelopes on this many local Dask '
                        'workers (1: in this process; default: the cores, %(default)s)')
    p.add_argument('--scheduler', metavar='ADDRESS',
                   help='run the tasks on the Dask cluster at ADDRESS instead')
    p.add_argument('--cache', type=Path,
                   help='cache of plant envelopes and draws (default: ~/.cache/dlmpc_ros)')
    p.add_argument('--resume', action='store_true',
                   help='fast drift runs: keep the runs already in OUT that were made with '
                        'the same settings and models folder, run only the others (each '
                        'run is saved as it finishes)')
    p.add_argument('--out', type=Path, required=True, help='output directory')
    args = p.parse_args(argv)
    args.models_dir = args.models_dir or default_models_dir()
    if args.suite:
        clash = [name for name, given in (
            ('--scenario', args.scenario), ('--scenario-param', args.scenario_param),
            ('--bench', args.bench), ('--measurement-noise', args.measurement_noise),
            ('--free-run', args.free_run), ('--bag', args.bag),
            ('--benchmark lock', args.benchmark == 'lock')) if given]
        if clash:
            p.error(f'--suite sets the scenarios, benches and noise of its conditions and '
                    f'runs fast drift runs; it takes no {", ".join(clash)}')
        args.fast = True
        args.conditions = SUITES[args.suite]()
        unknown = [c for c in args.condition if c not in args.conditions]
        if unknown:
            p.error(f'--suite {args.suite} has no condition {", ".join(unknown)}; its '
                    f'conditions: {", ".join(args.conditions)}')
        if args.condition:
            args.conditions = {k: c for k, c in args.conditions.items()
                               if k in args.condition}
        args.seed = args.seed or list(SUITE_SEEDS[args.suite])
        args.controller = args.controller or list(SUITE_CONTROLLERS[args.suite])
    elif args.condition:
        p.error('--condition selects conditions of a --suite')
    if args.lock_k is not None and (args.benchmark != 'lock' or not -0.3 <= args.lock_k <= 0.3):
        p.error('--lock-k applies to --benchmark lock and must be in [-0.3, 0.3]')
    args.budget = sorted(set(args.budget or [1000]))
    if args.workers < 1 or args.starts < 1 or args.budget[0] < 1:
        p.error('--workers, --starts and --budget must be >= 1')
    try:
        args.custom_plant = (plant_parameters(parse_plant(args.plant)) if args.plant
                             else None)
    except ValueError as err:
        p.error(str(err))
    if args.measurement_noise and not args.fast:
        p.error('--measurement-noise applies to --fast runs (a graph run measures the '
                'laser node as it is)')
    if not 0 <= args.measurement_noise < 1:
        p.error('--measurement-noise must be in [0, 1)')
    if args.measurement_round_trips < 1:
        p.error('--measurement-round-trips must be >= 1')
    if not (args.settle_tolerance >= 0 and args.settle_timeout >= 1):
        p.error('--settle-tolerance must be >= 0 and --settle-timeout >= 1')
    args.settle = {'settle_tolerance': args.settle_tolerance,
                   'settle_timeout': args.settle_timeout}
    try:
        bench = parse_bench(args.bench)
    except ValueError as err:
        p.error(str(err))
    args.bench = bench.changes()
    if args.measurement_noise and 'detector_noise' in args.bench:
        p.error('give the detector noise once: --measurement-noise or --bench '
                'detector_noise=...')
    if args.bag and (args.scenario or args.controller or args.seed or args.fast
                     or args.plant or args.plant_family):
        p.error('--bag evaluates recorded runs; it takes no --scenario, --controller, '
                '--seed, --fast or plant')
    if args.benchmark == 'lock' and (args.scenario or args.seed):
        p.error('--benchmark lock draws its own starts; it takes no --scenario or --seed')
    if args.bag:
        return args
    args.scenario = (list(dict.fromkeys(c.scenario for c in args.conditions.values()))
                     if args.suite else args.scenario or ['sinusoidal'])
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


def run_specs(args: argparse.Namespace, plant: dict | None = None) -> list[RunSpec]:
    """The runs the arguments ask for on one plant: scenarios x seeds x controllers."""
    mode = 'fast' if args.fast else ('graph-free-run' if args.free_run else 'graph-lockstep')
    if args.suite:  # conditions x seeds x controllers
        return [RunSpec(c.scenario, seed, controller, dict(c.settings), args.round_trips,
                        args.period, args.max_step, 0.0, mode, dict(plant or {}),
                        measurement_round_trips=args.measurement_round_trips,
                        bench=dict(c.bench), condition=c.name, **args.settle)
                for c, seed, controller in itertools.product(args.conditions.values(),
                                                             args.seed, args.controller)]
    return [RunSpec(scenario, seed, controller, args.settings[scenario], args.round_trips,
                    args.period, args.max_step, args.measurement_noise, mode, dict(plant or {}),
                    measurement_round_trips=args.measurement_round_trips, bench=args.bench,
                    **args.settle)
            for scenario, seed, controller in itertools.product(args.scenario, args.seed,
                                                                args.controller)]


@dataclass
class Plant:
    """A plant of the run: its label, physical parameters and envelope."""

    label: str
    parameters: dict
    envelope: dict | None = None


def resolve_plants(args: argparse.Namespace, tables: dict, tables_path: Path) -> list[Plant]:
    """The plants the arguments ask for, with their envelopes (drawn and computed as
    tasks, cached): the nominal plant's is the baseline tables' mirrored envelope."""
    cache = None if args.cache is None else str(args.cache)
    plants = []
    if args.nominal or not (args.plant or args.plant_family):
        plants.append(Plant('nominal', {}, tables))
    if args.custom_plant is not None:
        from dlmpc_ros.core.plants import plant_fingerprint
        cavity = parse_plant(args.plant)
        plants.append(Plant(f'plant-{plant_fingerprint(cavity)}', args.custom_plant))
    if args.plant_family:
        tasks = [PlantTask(str(tables_path), cache, seed=seed) for seed in args.plant_family]
        draws = _checked(run_tasks(draw_task, tasks, args.workers, args.scheduler,
                                   desc='plant draws'))
        plants += [Plant(f'family-{seed}', draw['plant'])
                   for seed, draw in zip(args.plant_family, draws)]
    todo = [p for p in plants if p.envelope is None]
    if todo:
        tasks = [PlantTask(str(tables_path), cache, plant=p.parameters) for p in todo]
        envelopes = _checked(run_tasks(envelope_task, tasks, args.workers, args.scheduler,
                                       desc='plant envelopes'))
        for plant, envelope in zip(todo, envelopes):
            plant.envelope = envelope
    return plants


def _checked(results: list) -> list:
    """The results, or RuntimeError naming the failed tasks."""
    failed = [r for r in results if isinstance(r, TaskFailure)]
    if failed:
        raise RuntimeError('; '.join(str(f) for f in failed))
    return results


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
              f'decisions{report.skipped_text()}: {summary_line(metrics)}', flush=True)
    write_summary(args.out, runs)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    tables_path = args.models_dir / 'oracle.npz'
    try:
        tables = load_baselines(tables_path)
    except (ModelFileError, FileNotFoundError, ValueError) as err:
        print(f'dlmpc-evaluate: {err}', file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    if args.bag:
        code = evaluate_bags(args, tables)
        if code == 0:
            print(f'dlmpc-evaluate: wrote {args.out}/metrics.json, table.md and figures/')
        return code
    for spec in args.controller:  # a bad spec stops here, not on every worker
        try:
            build(spec, args.models_dir, AngleLimits(max_step=args.max_step), initial_k=0.0)
        except ControllerSpecError as err:
            print(f'dlmpc-evaluate: {err}', file=sys.stderr)
            return 2
    started = time.monotonic()
    try:
        plants = resolve_plants(args, tables, tables_path)
        if args.benchmark == 'lock':
            return lock_benchmark(args, plants, started)
        return drift_benchmark(args, plants, started)
    except (ModelFileError, FileNotFoundError, RuntimeError, ValueError) as err:
        print(f'dlmpc-evaluate: {err}', file=sys.stderr)
        return 1


def drift_benchmark(args: argparse.Namespace, plants: list[Plant], started: float) -> int:
    """Every plant x scenario x seed x controller run, their metrics, tables, figures
    (``started``: when the whole command, plant envelopes included, began)."""
    nested = len(plants) > 1 or plants[0].label != 'nominal'
    jobs = [(plant, spec) for plant in plants for spec in run_specs(args, plant.parameters)]
    if args.fast:
        records = [_finished(_run_dir(args.out, plant, spec, nested), spec, args.models_dir)
                   if args.resume else None for plant, spec in jobs]
        todo = [i for i, record in enumerate(records) if record is None]
        if args.resume:
            print(f'dlmpc-evaluate: {len(jobs) - len(todo)} of {len(jobs)} runs already in '
                  f'{args.out}', flush=True)

        def save(j: int, record: RunRecord | TaskFailure) -> None:
            if not isinstance(record, TaskFailure):
                record.save(_run_dir(args.out, *jobs[todo[j]], nested) / 'record.npz')

        tasks = [RunTask(jobs[i][1], str(args.models_dir)) for i in todo]
        for i, record in zip(todo, run_tasks(run_task, tasks, args.workers, args.scheduler,
                                             desc='runs', torch='dlmpc' in args.controller,
                                             on_result=save)):
            records[i] = record
    else:  # graph runs: one bringup at a time, each on the run's own domain
        records = []
        for i, (plant, spec) in enumerate(jobs):
            run_dir = _run_dir(args.out, plant, spec, nested)
            records.append(run_spec(spec, args.models_dir, run_dir, args.domain_id))
            print(f'[{i + 1}/{len(jobs)}] graph run {run_dir.name} done', flush=True)
    runs, failed = [], 0
    for (plant, spec), record in zip(jobs, records):
        if isinstance(record, TaskFailure):
            failed += 1
            print(f'dlmpc-evaluate: {plant.label} {spec.scenario} seed {spec.seed} '
                  f'{spec.controller} failed: {record.error}', file=sys.stderr)
            continue
        run_dir = _run_dir(args.out, plant, spec, nested)
        metrics = measure(record, plant.envelope, run_dir)
        runs.append({'plant': plant.label, 'scenario': spec.scenario, 'seed': spec.seed,
                     'controller': spec.controller, 'metrics': metrics, 'meta': record.meta,
                     'record': record, **({'condition': spec.condition} if spec.condition
                                          else {})})
        print(f'{plant.label} {spec.condition or spec.scenario} seed {spec.seed} '
              f'{spec.controller}: {summary_line(metrics)}', flush=True)
    for plant in plants:
        mine = [r for r in runs if r['plant'] == plant.label]
        if not mine:
            continue
        out = args.out / plant.label if nested else args.out
        out.mkdir(parents=True, exist_ok=True)
        write_summary(out, [{k: v for k, v in r.items() if k != 'record'} for r in mine],
                      plant=plant.parameters)
        for scenario_name, seed in itertools.product([] if args.suite else args.scenario,
                                                     args.seed):  # no figures of a suite
            group = {r['controller']: r['record'] for r in mine
                     if r['scenario'] == scenario_name and r['seed'] == seed}
            if not group:
                continue
            shown = 'dlmpc' if 'dlmpc' in group else next(iter(group))
            title = f'{plant.label}: {scenario_name}, seed {seed}'
            plot_tracking(group, plant.envelope, shown, title,
                          out / 'figures' / f'{scenario_name}-s{seed}-tracking.png')
            if 'dlmpc' in group:
                plot_surrogate(group['dlmpc'], f'{scenario_name}, seed {seed}',
                               out / 'figures' / f'{scenario_name}-s{seed}-surrogate.png')
    if nested:
        write_plant_table(args.out, [{k: v for k, v in r.items() if k != 'record'}
                                     for r in runs], {p.label: p.parameters for p in plants},
                          round(time.monotonic() - started, 1), args.workers)
    summaries = [{k: v for k, v in r.items() if k != 'record'} for r in runs]
    if args.suite:
        write_suite(args.out, args.suite, args.conditions, summaries,
                    {p.label: p.parameters for p in plants},
                    {'seeds': args.seed, 'controllers': args.controller,
                     'round_trips': args.round_trips, 'period': args.period,
                     'max_step': args.max_step,
                     'measurement_round_trips': args.measurement_round_trips,
                     'workers': args.workers,
                     'wall_seconds': round(time.monotonic() - started, 1)})
    for run in over_envelope(summaries):
        print(f'dlmpc-evaluate: {over_envelope_warning(run)}', file=sys.stderr)
    print(f'dlmpc-evaluate: wrote {args.out}/metrics.json, table.md'
          + (f', {args.suite}.md, {args.suite}.json' if args.suite else ' and figures/')
          + f' ({len(runs)} runs, {failed} failed, {time.monotonic() - started:.0f} s)')
    return 1 if failed else 0


def _finished(run_dir: Path, spec: RunSpec, models_dir: Path) -> RunRecord | None:
    """The run's saved record, if it was made with these settings and models."""
    try:
        record = RunRecord.load(run_dir / 'record.npz')
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile):
        # absent, cut short by a kill, or not a record
        return None
    wanted = json.loads(json.dumps(spec.meta(models_dir)))
    if spec.bench:  # the record keeps every bench setting, the spec those not ideal
        wanted['bench'] = spec.bench_config.to_dict()
    return record if all(record.meta.get(k) == v for k, v in wanted.items()) else None


def _run_dir(out: Path, plant: Plant, spec: RunSpec, nested: bool) -> Path:
    name = f'{spec.condition or spec.scenario}-s{spec.seed}-{label(spec.controller)}'
    return (out / plant.label / name) if nested else out / name


def lock_benchmark(args: argparse.Namespace, plants: list[Plant], started: float) -> int:
    """The auto-mode-locking benchmark of every controller on every plant."""
    per_task = 10
    jobs, tasks = [], []
    budgets, headline = args.budget, args.budget[0]  # a sweep runs at the largest
    for plant in plants:
        for controller in args.controller:
            spec = LockSpec(controller, args.starts, budgets[-1], period=args.period,
                            max_step=args.max_step, drift=args.lock_drift, k=args.lock_k,
                            plant=dict(plant.parameters), bench=dict(args.bench))
            for first in range(0, args.starts, per_task):
                jobs.append((plant.label, controller, spec))
                tasks.append(LockTask(spec, tuple(range(first, min(first + per_task,
                                                                   args.starts))),
                                      str(args.models_dir), plant.envelope['K'],
                                      plant.envelope['O_star']))
    results = run_tasks(run_starts, tasks, args.workers, args.scheduler, desc='lock starts',
                        torch='dlmpc' in args.controller)
    failed = [r for r in results if isinstance(r, TaskFailure)]
    for failure in failed:
        print(f'dlmpc-evaluate: {failure}', file=sys.stderr)
    summary: dict = {'settings': {'starts': args.starts, 'budget': headline,
                                  'budgets': budgets,
                                  'drift': args.lock_drift, 'K': args.lock_k,
                                  'hold_periods': 20,
                                  'lock_fraction': 0.5, 'period': args.period},
                     'plants': {}}
    for plant in plants:
        entry = {'plant': plant.parameters, 'controllers': {}}
        for controller in args.controller:
            starts = [s for (label, name, _), r in zip(jobs, results)
                      if label == plant.label and name == controller
                      and not isinstance(r, TaskFailure) for s in r]
            spec = next(spec for label, name, spec in jobs
                        if label == plant.label and name == controller)
            sweep = sweep_metrics(starts, spec, budgets)
            entry['controllers'][controller] = {**sweep[str(headline)], 'budgets': sweep}
            for budget, m in sweep.items():
                print(f'{plant.label} {controller} (budget {budget}): locked '
                      f'{m["locked"]}/{m["starts"]}, median {m["median_round_trips"]} round '
                      f'trips, p90 {m["p90_round_trips"]}', flush=True)
        summary['plants'][plant.label] = entry
        plot_lock_times({name: m['budgets'][str(budgets[-1])]
                         for name, m in entry['controllers'].items()}, budgets[-1],
                        f'{plant.label}: {args.starts} cold starts',
                        args.out / f'lock-{plant.label}.png' if len(plants) > 1
                        else args.out / 'lock.png', budgets if len(budgets) > 1 else ())
    if len(plants) == 1:  # the one plant's figures at the top level
        summary.update(summary['plants'][plants[0].label]['controllers'])
    summary['wall_seconds'] = round(time.monotonic() - started, 1)
    (args.out / 'lock.json').write_text(json.dumps(summary, indent=1))
    (args.out / 'lock.md').write_text(lock_table(summary))
    print(f'dlmpc-evaluate: wrote {args.out}/lock.json, lock.md and the figures')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
