"""Tune the GA and ESC baselines with Optuna on the development plants (issue 35).

One Optuna study per method (``--method ga`` or ``esc``), TPE sampler seeded by
``--seed``. Trial 0 is always the shipped settings (:class:`GAConfig` /
:class:`ESCConfig` defaults, as near as the search space holds them), so every study
carries its own "before". Every trial runs in this one process (no Dask workers; numba on
``--threads`` threads, default 1) and scores, on each chosen development plant
(``--plants nominal 1 ... 8``; the held-out plants 101-108 are refused):

- **lock**: ``--starts`` cold starts as :mod:`dlmpc_ros.evaluation.lock_benchmark` runs
  them (random angles, the ``noise`` field, K drawn in [-0.3, 0.3] and held, a lock is
  O >= 0.5 O*(K) held for 20 periods), ``--budget`` round trips each, from the starts of
  ``--lock-seed`` (default 1: the benchmark reports seed 0, which is not tuned on). A
  start scores ``1 - 0.5 t / budget`` if it locked at round trip t, else 0 (success
  first, then speed);
- **drift**: mean O / O* of a ``--drift-round-trips`` run per ``--drift-scenario`` and
  ``--drift-seed`` (default: sinusoidal, seed 11, not one of the evaluation's seeds 1-3)
  from its random initial angles, as ``dlmpc-evaluate --fast`` runs it.

The objective (maximized) is ``lock_weight x mean lock score + (1 - lock_weight) x mean
drift ratio`` over the plants (``--lock-weight``, default 0.5). After each plant the
running objective is reported, and a trial below the median of the earlier ones there is
pruned (Optuna's MedianPruner; ``--no-prune`` turns it off).

GA: population, generations, elite, tournament, crossover, mutation rate and scale,
patience, and the dwell per evaluation as a multiple of the laser's settle time: before
the study the settle time is measured on every chosen plant (``--settle-lasers`` lasers
run from the noise field at random angles, the previous individual, then move, half to
the envelope's best angles for their K, half to other random angles, as a GA's
individuals do; the round trips until O stays within 5 % of the envelope's mean O* of
where it ends; its ``--settle-quantile``, default 0.75, over the lasers, one still moving
after 600 round trips counting as 600) and ``dwell = max(1, ceil(dwell_factor x
max(settle, period) / period))`` periods with the slowest plant's settle time
(``--settle-round-trips N`` gives it instead; on the nominal cavity most moves settle
within a period, so the dwell spans 1-5 periods). ESC:
the dither amplitudes (the shipped per-angle shape times a scale), the dither frequency
set (validated sets), the gain, the high- and low-pass constants, the objective's
normalization and the largest mean step.

Writes ``OUT/<method>.json`` (the arguments, the settle times, every trial's parameters,
resolved settings, per-plant values, state and wall time; rewritten after every trial)
and ``OUT/<method>.md`` (the best settings and the shipped reference). Defaults are
changed by hand, only from a full study. ``--storage`` (an Optuna storage URL, e.g.
``sqlite:///tune.db``) keeps the study for a later run with the same ``--method``.

Usage::

    python bench/tune_baselines.py --method ga --trials 60 --plants nominal 1 2 3 4 5 6 7 8 \\
        --starts 4 --budget 10000 --out bench/results/tune_baselines
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
METHODS = ('ga', 'esc')
#: Development plants: the nominal cavity and family seeds 1-8.
DEVELOPMENT = ('nominal', *(str(s) for s in range(1, 9)))
#: Family seeds of the held-out plants, never tuned on.
HELD_OUT = range(101, 109)
#: A start's score when it locks at the last round trip, relative to one at round trip 0.
LATE_LOCK_SCORE = 0.5
#: Dither frequency sets of the ESC search [cycles per control period]; each passes
#: ESCConfig's separation check (checked by the test). ``shipped`` is the default.
FREQUENCY_SETS: dict[str, tuple[float, ...]] = {
    'shipped': (0.06, 0.19, 0.31, 0.44),
    'alternate': (0.05, 0.13, 0.21, 0.37),
    'half': (0.03, 0.095, 0.155, 0.22),
    'third': (0.021, 0.0665, 0.1085, 0.154),
}
#: Range of the GA's dwell per evaluation, in settle times.
DWELL_FACTORS = (0.1, 5.0)
#: The settle measurement: warm-up and window after the move [round trips], and the band
#: (fraction of the envelope's mean O*) O must stay in around where it ends.
SETTLE_WARM, SETTLE_WINDOW, SETTLE_BAND, SETTLE_TAIL = 1000, 600, 0.05, 100


@dataclass
class Plant:
    """A development plant of the study."""

    label: str           # 'nominal' or 'family-N'
    parameters: dict     # physical parameters that differ from the nominal cavity
    envelope: dict       # 'K', 'O_star', 'angles' (the best angles at each K)
    settle: dict | None = None


# -- arguments ---------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='tune_baselines.py',
                                description=__doc__.split('\n\n')[0])
    p.add_argument('--method', required=True, choices=METHODS, help='the baseline to tune')
    p.add_argument('--trials', type=int, default=50, help='trials of the study')
    p.add_argument('--plants', nargs='+', default=['nominal'], metavar='PLANT',
                   help="development plants: 'nominal' and family seeds 1-8, or 'all' "
                        '(default: nominal)')
    p.add_argument('--starts', type=int, default=3, help='cold starts per plant and trial')
    p.add_argument('--budget', type=int, default=10000,
                   help='round trips per cold start (more than the 20-period hold)')
    p.add_argument('--lock-seed', type=int, default=1,
                   help='seed of the cold starts (the benchmark reports seed 0)')
    p.add_argument('--drift-round-trips', type=int, default=5000,
                   help='round trips of each drift run (0: no drift part)')
    p.add_argument('--drift-scenario', action='append', metavar='PRESET',
                   help='drift preset, repeatable (default: sinusoidal)')
    p.add_argument('--drift-seed', action='append', type=int, metavar='SEED',
                   help='seed of the drift runs, repeatable (default: 11)')
    p.add_argument('--lock-weight', type=float, default=0.5,
                   help='weight of the lock score in the objective, in [0, 1]')
    p.add_argument('--seed', type=int, default=0, help='seed of the TPE sampler')
    p.add_argument('--startup-trials', type=int, default=10,
                   help='random trials before TPE models the results')
    p.add_argument('--no-prune', action='store_true', help='run every trial on every plant')
    p.add_argument('--settle-round-trips', type=int, metavar='N',
                   help='ga: the settle time [round trips] instead of measuring it')
    p.add_argument('--settle-lasers', type=int, default=32,
                   help='ga: lasers of the settle measurement per plant')
    p.add_argument('--settle-quantile', type=float, default=0.75,
                   help="ga: the quantile of the lasers' settle times the dwell is made from")
    p.add_argument('--threads', type=int, default=1, help='numba threads (default 1)')
    p.add_argument('--storage', metavar='URL',
                   help='Optuna storage (e.g. sqlite:///tune.db) to keep or resume the study')
    p.add_argument('--confirm', type=Path, metavar='STUDY_JSON',
                   help="no study: run a study's best and shipped settings (its "
                        "OUT/<method>.json) on this run's starts and drift seeds, which "
                        "should differ from the study's; writes OUT/<method>_confirm.{json,md}")
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models',
                   help='model files (the nominal envelope, models/oracle.npz)')
    p.add_argument('--out', type=Path, default=ROOT / 'bench' / 'results' / 'tune_baselines')
    args = p.parse_args(argv)
    plants = list(DEVELOPMENT) if args.plants == ['all'] else args.plants
    for plant in plants:
        if plant.isdigit() and int(plant) in HELD_OUT:
            p.error(f'--plants {plant}: plants 101-108 are held out (reports only); tune on '
                    f"the development plants: {', '.join(DEVELOPMENT)} or 'all'")
        if plant not in DEVELOPMENT:
            p.error(f"--plants {plant!r}: not a development plant; one of "
                    f"{', '.join(DEVELOPMENT)} or 'all'")
    args.plants = list(dict.fromkeys(plants))
    from dlmpc_ros.evaluation.presets import PRESETS
    args.drift_scenario = list(dict.fromkeys(args.drift_scenario or ['sinusoidal']))
    unknown = [s for s in args.drift_scenario if s not in PRESETS]
    if unknown:
        p.error(f'--drift-scenario {unknown[0]!r}: one of {", ".join(PRESETS)}')
    args.drift_seed = list(dict.fromkeys(args.drift_seed or [11]))
    hold = hold_round_trips()
    for name, value, least in (('--trials', args.trials, 1), ('--starts', args.starts, 1),
                               ('--threads', args.threads, 1),
                               ('--startup-trials', args.startup_trials, 0),
                               ('--drift-round-trips', args.drift_round_trips, 0),
                               ('--settle-lasers', args.settle_lasers, 1),
                               ('--lock-seed', args.lock_seed, 0)):
        if value < least:
            p.error(f'{name} must be >= {least}, got {value}')
    if args.budget <= hold:
        p.error(f'--budget must exceed the lock hold of {hold} round trips (20 periods), '
                f'got {args.budget}')
    if not 0 <= args.lock_weight <= 1:
        p.error(f'--lock-weight must be in [0, 1], got {args.lock_weight}')
    if args.lock_weight < 1 and args.drift_round_trips == 0:
        p.error('--drift-round-trips 0 leaves no drift part: give --lock-weight 1')
    if not 0 <= args.settle_quantile <= 1:
        p.error(f'--settle-quantile must be in [0, 1], got {args.settle_quantile}')
    if args.settle_round_trips is not None and args.settle_round_trips < 1:
        p.error(f'--settle-round-trips must be >= 1, got {args.settle_round_trips}')
    if args.settle_round_trips is not None and args.method != 'ga':
        p.error('--settle-round-trips sets the GA dwell; esc has none')
    if not (args.models_dir / 'oracle.npz').is_file():
        p.error(f'--models-dir {args.models_dir}: no oracle.npz (the nominal envelope)')
    return args


def hold_round_trips() -> int:
    from dlmpc_ros.evaluation.lock_benchmark import LockSpec
    spec = LockSpec('ga')
    return spec.hold_periods * spec.period


# -- plants and their settle time --------------------------------------------------------
def resolve_plant(name: str, tables: dict) -> Plant:
    """A development plant with its envelope (a family plant's is drawn and computed
    once, then cached under ~/.cache/dlmpc_ros, as dlmpc-evaluate does)."""
    if name == 'nominal':
        return Plant('nominal', {}, {key: tables[key] for key in ('K', 'O_star', 'angles')})
    from dlmpc_ros.core.plants import NOMINAL, PlantFamily, plant_parameters
    from dlmpc_ros.training.envelope import cached_plant_envelope, draw_plant
    cavity, _ = draw_plant(PlantFamily(), int(name), tables)
    nominal = plant_parameters(NOMINAL)
    changed = {k: v for k, v in plant_parameters(cavity).items() if v != nominal[k]}
    return Plant(f'family-{name}', changed, cached_plant_envelope(cavity, tables))


def settle_time(plant: Plant, lasers: int = 32, quantile: float = 0.75, seed: int = 0,
                warm: int = SETTLE_WARM, window: int = SETTLE_WINDOW, band: float = SETTLE_BAND,
                tail: int = SETTLE_TAIL) -> dict:
    """How long this plant's laser takes to settle after a GA's move: ``lasers`` lasers,
    each at a K of the envelope's grid, run ``warm`` round trips from the noise field at
    random angles (the previous individual), then move, half of them to the envelope's
    best angles for their K (a good individual), half to other random angles. A laser's
    settle time is the round trips after the move until O stays within ``band`` x the
    envelope's mean O* of its mean over the window's last ``tail`` round trips; one whose
    O still moves more than that over the tail counts as ``window``. Returns the
    ``quantile`` of the settle times (``round_trips``, what the dwell is made from), their
    median, each laser's time and how many settled within the window."""
    from dlmpc_ros.core.cavity import Cavity
    from dlmpc_ros.core.plants import NOMINAL
    rng = np.random.default_rng(seed)
    envelope = plant.envelope
    grid = rng.integers(0, len(envelope['K']), lasers)
    cavity = Cavity(replace(NOMINAL, **plant.parameters), batch=lasers,
                    angles=rng.uniform(-np.pi / 2, np.pi / 2, (lasers, 4)),
                    birefringence=envelope['K'][grid], initial='noise',
                    seed=int(rng.integers(2 ** 31)))
    cavity.run(warm)
    good = np.arange(lasers) < (lasers + 1) // 2
    cavity.set_angles(np.where(good[:, None], envelope['angles'][grid],
                               rng.uniform(-np.pi / 2, np.pi / 2, (lasers, 4))))
    o = np.nan_to_num(cavity.run(window).O, nan=0.0)   # (window, lasers)
    scale = band * float(np.mean(envelope['O_star']))
    end = o[-tail:].mean(axis=0)
    times = []
    for b in range(lasers):
        outside = np.flatnonzero(np.abs(o[:, b] - end[b]) > scale)
        moving = np.ptp(o[-tail:, b]) > 2 * scale   # still moving at the window's end
        times.append(window if moving else 0 if outside.size == 0 else int(outside[-1]) + 1)
    return {'round_trips': float(np.quantile(times, quantile)), 'quantile': quantile,
            'median_round_trips': float(np.median(times)),
            'settled': int(sum(t < window for t in times)), 'lasers': lasers,
            'to_best_angles': [t for t, g in zip(times, good) if g],
            'to_random_angles': [t for t, g in zip(times, good) if not g],
            'window': window, 'band': band, 'warm': warm}


# -- search spaces -----------------------------------------------------------------------
def ga_settings(params: dict, settle_round_trips: float, period: int = 10):
    """GAConfig of a GA trial's parameters: the dwell is ``dwell_factor`` settle times,
    at least one period (a measurement takes one) and a settle time no shorter than it."""
    from dlmpc_ros.control.ga import GAConfig
    dwell = max(1, math.ceil(params['dwell_factor'] * max(settle_round_trips, period)
                             / period))
    return GAConfig(**{k: v for k, v in params.items() if k != 'dwell_factor'}, dwell=dwell)


def ga_space(trial, settle_round_trips: float):
    params = {'population': trial.suggest_int('population', 6, 40),
              'generations': trial.suggest_int('generations', 3, 20),
              'elite': trial.suggest_int('elite', 0, 4),
              'tournament': trial.suggest_int('tournament', 2, 5),
              'crossover': trial.suggest_float('crossover', 0.3, 1.0),
              'mutation': trial.suggest_float('mutation', 0.05, 0.6),
              'mutation_sigma': trial.suggest_float('mutation_sigma', 0.05, 0.8, log=True),
              'patience': trial.suggest_int('patience', 2, 8),
              'dwell_factor': trial.suggest_float('dwell_factor', *DWELL_FACTORS, log=True)}
    return ga_settings(params, settle_round_trips)


def ga_shipped(settle_round_trips: float, period: int = 10) -> dict:
    """The shipped GAConfig as parameters of the space (dwell as a factor, clipped)."""
    from dlmpc_ros.control.ga import GAConfig
    d = GAConfig()
    factor = (d.dwell - 0.5) * period / max(settle_round_trips, period)  # ceil: d.dwell
    factor = min(max(factor, DWELL_FACTORS[0]), DWELL_FACTORS[1])
    return {'population': d.population, 'generations': d.generations, 'elite': d.elite,
            'tournament': d.tournament, 'crossover': d.crossover, 'mutation': d.mutation,
            'mutation_sigma': d.mutation_sigma, 'patience': d.patience,
            'dwell_factor': factor}


def esc_settings(params: dict):
    """ESCConfig of an ESC trial's parameters."""
    from dlmpc_ros.control.esc import ESCConfig
    shape = np.asarray(ESCConfig().amplitudes)
    amplitude = tuple(float(a) for a in np.minimum(shape * params['amplitude_scale'], 0.5))
    return ESCConfig(amplitude=amplitude,
                     frequencies=FREQUENCY_SETS[params['frequency_set']],
                     gain=params['gain'], high_pass=params['high_pass'],
                     low_pass=params['low_pass'], normalize=params['normalize'],
                     max_mean_step=params['max_mean_step'])


def esc_space(trial, settle_round_trips: float | None = None):
    from dlmpc_ros.control.esc import NORMALIZATIONS
    return esc_settings({
        'amplitude_scale': trial.suggest_float('amplitude_scale', 0.25, 8.0, log=True),
        'frequency_set': trial.suggest_categorical('frequency_set', list(FREQUENCY_SETS)),
        'gain': trial.suggest_float('gain', 1e-4, 1e-1, log=True),
        'high_pass': trial.suggest_float('high_pass', 0.02, 1.0, log=True),
        'low_pass': trial.suggest_float('low_pass', 0.02, 1.0, log=True),
        'normalize': trial.suggest_categorical('normalize', list(NORMALIZATIONS)),
        'max_mean_step': trial.suggest_float('max_mean_step', 0.005, 0.1, log=True)})


def esc_shipped(settle_round_trips: float | None = None) -> dict:
    from dlmpc_ros.control.esc import ESCConfig
    d = ESCConfig()
    shipped = {name for name, f in FREQUENCY_SETS.items() if f == tuple(d.frequencies)}
    return {'amplitude_scale': 1.0, 'frequency_set': shipped.pop(), 'gain': d.gain,
            'high_pass': d.high_pass, 'low_pass': d.low_pass, 'normalize': d.normalize,
            'max_mean_step': d.max_mean_step}


def builder(method: str, config) -> Callable:
    """``limits -> controller`` of the method with ``config`` (as its factory builds it)."""
    from dlmpc_ros.control.esc import ESCController
    from dlmpc_ros.control.ga import GAController
    if method == 'ga':
        return lambda limits: GAController(config, limits)
    return lambda limits: ESCController(config=config, limits=limits)


# -- scoring -----------------------------------------------------------------------------
def lock_starts(build: Callable, spec, envelope: dict) -> list[dict]:
    """``spec``'s cold starts (held K) run as
    :func:`dlmpc_ros.evaluation.lock_benchmark.run_starts` runs them, with a controller
    from ``build(limits)`` per start; the same per-start dicts."""
    from dlmpc_ros.control.step import AngleLimits
    from dlmpc_ros.evaluation.lock_benchmark import run_start
    if spec.drift != 'held':
        raise ValueError('the tuning runs the held-K lock benchmark only')
    limits = AngleLimits(max_step=spec.max_step)
    return [run_start(build(limits), spec, envelope, index) for index in range(spec.starts)]


def lock_score(starts: list[dict], budget: int) -> float:
    """Mean over the starts of ``1 - LATE_LOCK_SCORE x t / budget`` for a lock at round
    trip t, 0 for none."""
    return float(np.mean([1 - LATE_LOCK_SCORE * s['round_trips'] / budget if s['locked']
                          else 0.0 for s in starts]))


def drift_ratio(method: str, build: Callable, plant: Plant, scenario: str, seed: int,
                round_trips: int, models_dir: Path) -> float:
    """Mean O / O* of one fast drift run (``dlmpc-evaluate --fast``'s run)."""
    from dlmpc_ros.control.step import AngleLimits
    from dlmpc_ros.evaluation.metrics import run_metrics
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    spec = RunSpec(scenario, seed, method, round_trips=round_trips, plant=plant.parameters)
    record = run_fast(spec, models_dir, controller=build(AngleLimits(max_step=spec.max_step)))
    return float(run_metrics(record, plant.envelope)['oracle_ratio'])


def evaluate(args: argparse.Namespace, config, plants: list[Plant],
             report: Callable[[int, float, dict], None] | None = None) -> dict:
    """Per-plant lock and drift values of ``config`` and the objective. ``report(step,
    running objective, per-plant values so far)`` is called after each plant but the last
    (it may raise to prune the trial)."""
    from dlmpc_ros.evaluation.lock_benchmark import LockSpec
    build = builder(args.method, config)
    per_plant, objectives = {}, []
    for step, plant in enumerate(plants):
        started = time.perf_counter()
        spec = LockSpec(args.method, starts=args.starts, budget=args.budget,
                        seed=args.lock_seed, plant=dict(plant.parameters))
        starts = lock_starts(build, spec, plant.envelope)
        ratios = ([drift_ratio(args.method, build, plant, scenario, seed,
                               args.drift_round_trips, args.models_dir)
                   for scenario in args.drift_scenario for seed in args.drift_seed]
                  if args.drift_round_trips else [])
        entry = {'locked': sum(s['locked'] for s in starts), 'starts': len(starts),
                 'lock_score': lock_score(starts, args.budget),
                 'round_trips_to_lock': [s['round_trips'] for s in starts],
                 'drift_ratio': float(np.mean(ratios)) if ratios else None,
                 'drift_ratios': ratios,
                 'wall_s': round(time.perf_counter() - started, 2)}
        entry['objective'] = combine(args.lock_weight, entry['lock_score'], entry['drift_ratio'])
        per_plant[plant.label] = entry
        objectives.append(entry['objective'])
        if report is not None and step < len(plants) - 1:
            report(step, float(np.mean(objectives)), per_plant)
    values = list(per_plant.values())
    return {'objective': float(np.mean(objectives)),
            'lock_score': float(np.mean([v['lock_score'] for v in values])),
            'locked': sum(v['locked'] for v in values),
            'starts': sum(v['starts'] for v in values),
            'drift_ratio': (float(np.mean([v['drift_ratio'] for v in values]))
                            if args.drift_round_trips else None),
            'plants': per_plant}


def combine(weight: float, lock: float, drift: float | None) -> float:
    return weight * lock + (1 - weight) * (drift or 0.0)


# -- records -----------------------------------------------------------------------------
def trial_record(trial) -> dict:
    """A trial as JSON: number, state, params, settings, values, wall time."""
    attrs = trial.user_attrs
    wall = attrs.get('wall_s')
    if wall is None and trial.datetime_start and trial.datetime_complete:
        wall = (trial.datetime_complete - trial.datetime_start).total_seconds()
    return {'number': trial.number, 'state': trial.state.name, 'value': trial.value,
            'shipped': bool(attrs.get('shipped', False)), 'params': trial.params,
            'settings': attrs.get('settings'), 'values': attrs.get('values'),
            'wall_s': wall,
            'started': trial.datetime_start.isoformat() if trial.datetime_start else None}


def write_records(args: argparse.Namespace, study, plants: list[Plant], settle: float | None,
                  started: float, argv: Sequence[str] | None) -> tuple[Path, Path]:
    import optuna
    trials = [trial_record(t) for t in study.get_trials(deepcopy=False)]
    complete = [t for t in trials if t['state'] == 'COMPLETE']
    best = max(complete, key=lambda t: t['value']) if complete else None
    shipped = next((t for t in complete if t['shipped']), None)
    walls = [t['wall_s'] for t in complete if t['wall_s'] is not None]
    record = {
        'method': args.method, 'study': study.study_name,
        'command': 'python bench/tune_baselines.py ' + ' '.join(
            sys.argv[1:] if argv is None else argv),
        'optuna': optuna.__version__, 'sampler': f'TPESampler(seed={args.seed}, '
        f'n_startup_trials={args.startup_trials})',
        'pruner': None if args.no_prune else 'MedianPruner(n_startup_trials=5)',
        'settings': {k: (_shown(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        'objective': f'{args.lock_weight} x lock score (a start locked at round trip t '
                     f'scores 1 - {LATE_LOCK_SCORE} t / budget, else 0) + '
                     f'{1 - args.lock_weight:g} x mean O / O* of the drift runs, mean over '
                     'plants',
        'plants': {p.label: {'parameters': p.parameters, 'settle': p.settle} for p in plants},
        'settle_round_trips': settle,
        'trials': trials, 'best': best, 'shipped': shipped,
        'wall_s_per_complete_trial': float(np.mean(walls)) if walls else None,
        'wall_s': round(time.monotonic() - started, 1)}
    args.out.mkdir(parents=True, exist_ok=True)
    json_path, md_path = args.out / f'{args.method}.json', args.out / f'{args.method}.md'
    json_path.write_text(json.dumps(record, indent=1, default=str))
    md_path.write_text(summary_markdown(record))
    return json_path, md_path


def _shown(path: Path) -> str:
    """A path as the record shows it: relative to the repository when inside it."""
    path = Path(path).resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def summary_markdown(record: dict) -> str:
    s = record['settings']
    trials, best, shipped = record['trials'], record['best'], record['shipped']
    done = sum(t['state'] == 'COMPLETE' for t in trials)
    lines = [f"# Tuning the {record['method'].upper()} baseline (Optuna {record['optuna']})",
             '', f"`{record['command']}`", '',
             f"{len(trials)} trials ({done} complete, "
             f"{sum(t['state'] == 'PRUNED' for t in trials)} pruned) on "
             f"{', '.join(record['plants'])}; {s['starts']} cold starts per plant "
             f"(seed {s['lock_seed']}), budget {s['budget']} round trips; drift: "
             + (f"{', '.join(s['drift_scenario'])}, seeds "
                f"{', '.join(map(str, s['drift_seed']))}, {s['drift_round_trips']} round trips"
                if s['drift_round_trips'] else 'none')
             + f". Objective: {record['objective']}. Sampler {record['sampler']}, pruner "
             f"{record['pruner']}. {record['wall_s']:.0f} s in all"
             + (f", {record['wall_s_per_complete_trial']:.1f} s per complete trial."
                if record['wall_s_per_complete_trial'] else '.'), '']
    if len(trials) < 10:
        lines += ['**A smoke run, not a tuning**: too few trials to change the shipped '
                  'settings (a study: 50+ trials on all nine development plants).', '']
    elif len(trials) < 50 or len(record['plants']) < len(DEVELOPMENT):
        lines += [f"**A reduced study** ({len(trials)} trials on {len(record['plants'])} of "
                  f'the {len(DEVELOPMENT)} development plants): its best changes a default '
                  'only where `--confirm` on other cold starts and drift seeds agrees.', '']
    if record['settle_round_trips'] is not None:
        per = ', '.join(f"{k} {v['settle']['round_trips']:.0f} (median "
                        f"{v['settle']['median_round_trips']:.0f}, {v['settle']['settled']}/"
                        f"{v['settle']['lasers']} within {v['settle']['window']})"
                        for k, v in record['plants'].items() if v['settle'])
        lines += [f"Settle time of the laser after a GA's move (round trips, quantile "
                  f"{record['settings']['settle_quantile']}): {per or 'given'}; the dwell is "
                  f"ceil(dwell_factor x max({record['settle_round_trips']:.0f}, 10) / 10) "
                  'periods.',
                  '']
    lines += ['| trial | objective | lock score | locked | drift O/O* | wall [s] | settings |',
              '|---|---|---|---|---|---|---|']
    shown = [t for t in (best, shipped) if t is not None]
    shown = [t for i, t in enumerate(shown) if t not in shown[:i]]
    for t in shown:
        v = t['values']
        name = f"{t['number']} (" + ', '.join(
            ([] if not t['shipped'] else ['shipped']) + ([] if t is not best else ['best'])) + ')'
        drift = '-' if v['drift_ratio'] is None else f"{v['drift_ratio']:.3f}"
        lines.append(f"| {name} | {t['value']:.3f} | {v['lock_score']:.3f} | "
                     f"{v['locked']}/{v['starts']} | {drift} | {t['wall_s']:.1f} | "
                     f"`{json.dumps(t['settings'])}` |")
    if shown:
        lines += ['', 'Per plant (locked / starts, median round trips to lock, drift O/O*):', '',
                  '| trial | ' + ' | '.join(record['plants']) + ' |',
                  '|---|' + '---|' * len(record['plants'])]
        for t in shown:
            cells = []
            for plant in record['plants']:
                v = t['values']['plants'][plant]
                times = [r for r in v['round_trips_to_lock'] if r is not None]
                median = f'{np.median(times):.0f}' if times else '-'
                drift = '-' if v['drift_ratio'] is None else f"{v['drift_ratio']:.3f}"
                cells.append(f"{v['locked']}/{v['starts']}, {median}, {drift}")
            lines.append(f"| {t['number']}{' (shipped)' if t['shipped'] else ''} | "
                         + ' | '.join(cells) + ' |')
    if best is not None and not best['shipped']:
        kind = 'GAConfig' if record['method'] == 'ga' else 'ESCConfig'
        default = (shipped or {}).get('settings') or {}
        changed = {k: v for k, v in best['settings'].items() if default.get(k) != v}
        lines += ['', f'Best against the shipped settings: `{kind}('
                  + ', '.join(f'{k}={v!r}' for k, v in changed.items()) + ')`']
    lines += ['', '## Every trial', '', '| trial | state | objective | params | wall [s] |',
              '|---|---|---|---|---|']
    for t in trials:
        value = '-' if t['value'] is None else f"{t['value']:.3f}"
        wall = '-' if t['wall_s'] is None else f"{t['wall_s']:.1f}"
        params = ', '.join(f'{k}={v:.3g}' if isinstance(v, float) else f'{k}={v}'
                           for k, v in t['params'].items())
        lines.append(f"| {t['number']}{' (shipped)' if t['shipped'] else ''} | {t['state']} "
                     f"| {value} | {params} | {wall} |")
    return '\n'.join(lines) + '\n'


# -- the study ---------------------------------------------------------------------------
def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    import numba
    threads = numba.get_num_threads()
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    try:
        return confirm(args, argv) if args.confirm else study(args, argv)
    finally:
        numba.set_num_threads(threads)


def load_plants(args: argparse.Namespace) -> list[Plant]:
    """The chosen development plants with their envelopes."""
    from dlmpc_ros.learning.tables import load_baselines
    tables = load_baselines(args.models_dir / 'oracle.npz')
    plants = []
    for name in args.plants:
        t0 = time.monotonic()
        plants.append(resolve_plant(name, tables))
        print(f'plant {plants[-1].label}: envelope ready ({time.monotonic() - t0:.0f} s)',
              flush=True)
    return plants


def confirm(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    """A study's best and shipped settings, each on this run's starts and drift seeds."""
    from dlmpc_ros.control.esc import ESCConfig
    from dlmpc_ros.control.ga import GAConfig
    started = time.monotonic()
    study_record = json.loads(args.confirm.read_text())
    if study_record['method'] != args.method:
        raise SystemExit(f"--confirm {args.confirm}: a {study_record['method']} study, "
                         f'not {args.method}')
    kind = GAConfig if args.method == 'ga' else ESCConfig
    plants = load_plants(args)
    rows = {}
    for name in ('shipped', 'best'):
        trial = study_record[name]
        config = kind(**trial['settings'])
        t0 = time.monotonic()
        rows[name] = {'trial': trial['number'], 'settings': trial['settings'],
                      'study_value': trial['value'],
                      'values': evaluate(args, config, plants),
                      'wall_s': round(time.monotonic() - t0, 1)}
        v = rows[name]['values']
        print(f"{name} (trial {trial['number']}): {v['objective']:.3f} (locked "
              f"{v['locked']}/{v['starts']}, drift {v['drift_ratio']})", flush=True)
    command = 'python bench/tune_baselines.py ' + ' '.join(sys.argv[1:] if argv is None
                                                            else argv)
    record = {'method': args.method, 'command': command, 'study': _shown(args.confirm),
              'settings': {k: (_shown(v) if isinstance(v, Path) else v)
                           for k, v in vars(args).items()},
              'rows': rows, 'wall_s': round(time.monotonic() - started, 1)}
    args.out.mkdir(parents=True, exist_ok=True)
    json_path = args.out / f'{args.method}_confirm.json'
    json_path.write_text(json.dumps(record, indent=1, default=str))
    lines = [f'# Confirming the {args.method.upper()} study', '', f'`{command}`', '',
             f"Cold starts of seed {args.lock_seed} ({args.starts} per plant, budget "
             f"{args.budget}), drift seeds {', '.join(map(str, args.drift_seed))}: not the "
             'study\'s.', '',
             '| settings | study objective | objective here | lock score | locked | '
             'drift O/O* | ' + ' | '.join(p.label for p in plants) + ' |',
             '|---|---|---|---|---|---|' + '---|' * len(plants)]
    for name, row in rows.items():
        v = row['values']
        cells = [f"{p['locked']}/{p['starts']}, {p['drift_ratio']:.3f}"
                 if p['drift_ratio'] is not None else f"{p['locked']}/{p['starts']}"
                 for p in v['plants'].values()]
        drift = '-' if v['drift_ratio'] is None else f"{v['drift_ratio']:.3f}"
        lines.append(f"| {name} (trial {row['trial']}) | {row['study_value']:.3f} | "
                     f"{v['objective']:.3f} | {v['lock_score']:.3f} | "
                     f"{v['locked']}/{v['starts']} | {drift} | " + ' | '.join(cells) + ' |')
    (args.out / f'{args.method}_confirm.md').write_text('\n'.join(lines) + '\n')
    print(f'tune_baselines: wrote {json_path} ({time.monotonic() - started:.0f} s)')
    return 0


def study(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    """The study of ``args`` (numba's threads already set)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    started = time.monotonic()
    plants = load_plants(args)
    settle = None
    if args.method == 'ga':
        if args.settle_round_trips is not None:
            settle = float(args.settle_round_trips)
        else:
            for plant in plants:
                t0 = time.monotonic()
                plant.settle = settle_time(plant, args.settle_lasers, args.settle_quantile)
                print(f"plant {plant.label}: settles in {plant.settle['round_trips']:.0f} round "
                      f"trips (quantile {args.settle_quantile}; median "
                      f"{plant.settle['median_round_trips']:.0f}; {plant.settle['settled']}/"
                      f"{plant.settle['lasers']} within {plant.settle['window']}; "
                      f"{time.monotonic() - t0:.0f} s)", flush=True)
            settle = max(p.settle['round_trips'] for p in plants)
    space, shipped = (ga_space, ga_shipped) if args.method == 'ga' else (esc_space, esc_shipped)
    pruner = (optuna.pruners.NopPruner() if args.no_prune
              else optuna.pruners.MedianPruner(n_startup_trials=5))
    tuning = optuna.create_study(
        study_name=f'tune-{args.method}', direction='maximize', storage=args.storage,
        load_if_exists=args.storage is not None, pruner=pruner,
        sampler=optuna.samplers.TPESampler(seed=args.seed,
                                           n_startup_trials=args.startup_trials))
    if not any(t.user_attrs.get('shipped') for t in tuning.get_trials(deepcopy=False)):
        tuning.enqueue_trial(shipped(settle), user_attrs={'shipped': True})

    def objective(trial) -> float:
        t0 = time.perf_counter()
        config = space(trial, settle)
        trial.set_user_attr('settings', json.loads(json.dumps(asdict(config))))

        def report(step: int, value: float, per_plant: dict) -> None:
            trial.report(value, step)
            if trial.should_prune():
                trial.set_user_attr('values', {'objective_so_far': value,
                                               'plants': per_plant})
                trial.set_user_attr('wall_s', round(time.perf_counter() - t0, 2))
                raise optuna.TrialPruned()

        values = evaluate(args, config, plants, report)
        trial.set_user_attr('values', values)
        trial.set_user_attr('wall_s', round(time.perf_counter() - t0, 2))
        return values['objective']

    counter = iter(range(1, args.trials + 1))

    def progress(study, trial) -> None:
        wall = trial.user_attrs.get('wall_s', float('nan'))
        done = [t for t in study.get_trials(deepcopy=False) if t.value is not None
                and t.state.name == 'COMPLETE']
        best = max(done, key=lambda t: t.value) if done else None
        value = '-' if trial.value is None else f'{trial.value:.3f}'
        values = trial.user_attrs.get('values') or {}
        drift = values.get('drift_ratio')
        detail = (f" (locked {values['locked']}/{values['starts']}, drift "
                  f"{'-' if drift is None else f'{drift:.3f}'})" if 'locked' in values
                  else f" at {values['objective_so_far']:.3f} after "
                       f"{len(values['plants'])} plants" if values else '')
        print(f'[{next(counter)}/{args.trials}] {args.method} trial {trial.number} '
              f'{trial.state.name.lower()}: {value}{detail} in {wall:.1f} s; best '
              + (f'{best.value:.3f} (trial {best.number})' if best else '-'), flush=True)
        write_records(args, study, plants, settle, started, argv)

    tuning.optimize(objective, n_trials=args.trials, callbacks=[progress])
    json_path, md_path = write_records(args, tuning, plants, settle, started, argv)
    print(f'tune_baselines: wrote {json_path} and {md_path} '
          f'({time.monotonic() - started:.0f} s)')
    return 0


if __name__ == '__main__':
    os.environ.setdefault('OMP_NUM_THREADS', '1')   # one core per process, BLAS included
    sys.exit(main())
