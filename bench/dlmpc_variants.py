"""Closed-loop ablation of DL-MPC settings: each variant on every plant, scenario and seed.

A variant is a set of :class:`DLMPCConfig` overrides; every run goes through
``dlmpc-evaluate --fast``'s own run (:func:`dlmpc_ros.evaluation.runs.run_fast`: same
scenario presets, initial angles, servo limit and models) and is divided by its plant's
own envelope (the nominal tables for the nominal cavity, the cached per-plant envelope
otherwise), so a variant with no overrides reproduces the DL-MPC column of
``dlmpc-evaluate``.

Usage::

    python bench/dlmpc_variants.py --variants variants.json --seeds 1 2 3 \\
        --nominal --plant-family 101 --plant-family 102 --scenario sinusoidal \\
        --out bench/results/ablation.json --workers 2

``variants.json`` maps names to overrides, e.g. ``{"shipped": {}, "no planner":
{"planner": null}, "no survey": {"tracking": {"survey_patience": 1000000}}, "noisy":
{"measurement_noise": 0.01}, "other models": {"models_dir": "out/models"}}``
(``tracking``, ``acquisition`` and ``planner`` take the fields of their configs;
``measurement_noise`` is the run's relative noise on the measured E and M, and
``measurement_round_trips`` how many of a period's last round trips its measurement
averages;
``models_dir`` a models folder, environment variables such as ``${OUT}`` expanded).
With ``--lock-starts N`` each variant runs the lock benchmark instead (the first N cold
starts of ``dlmpc-evaluate --benchmark lock`` on every plant, in blocks of 10) and the
table gives the starts locked and the median control periods to lock per plant.
Runs go on Dask (:func:`dlmpc_ros.scaleout.run_tasks`). Writes the runs' metrics (plus
the fraction of periods in each mode) as JSON and a markdown table of mean O / O* per
variant, plant group (the nominal cavity; the family plants pooled) and scenario (mean
over plants and seeds, min-max of the runs).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dlmpc_ros.scaleout import TaskFailure, default_workers, run_tasks

if TYPE_CHECKING:
    from dlmpc_ros.control.dlmpc_config import DLMPCConfig

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ('sinusoidal', 'chirp', 'random_walk', 'steps')


@dataclass(frozen=True)
class VariantRun:
    """One run of the ablation."""

    variant: str
    overrides: dict
    plant: str            # 'nominal' or a family seed
    scenario: str         # a scenario preset, or a suite condition's name
    seed: int
    round_trips: int
    models_dir: str
    condition: dict | None = None  # a stress suite condition's to_dict() (else None)


@dataclass(frozen=True)
class LockBlock:
    """A block of cold starts of the lock benchmark for one variant on one plant."""

    variant: str
    overrides: dict
    plant: str
    indices: tuple[int, ...]
    models_dir: str


def plant_and_envelope(plant: str, models_dir: Path) -> tuple[dict, dict]:
    """The plant's physical parameters that differ from the nominal cavity and the
    envelope its ratios divide by."""
    from dlmpc_ros.core.plants import NOMINAL, PlantFamily, plant_parameters
    from dlmpc_ros.learning.tables import load_baselines
    from dlmpc_ros.training.envelope import cached_plant_envelope, draw_plant
    tables = load_baselines(models_dir / 'oracle.npz')
    if plant == 'nominal':
        return {}, tables
    cavity, _ = draw_plant(PlantFamily(), int(plant), tables)
    nominal = plant_parameters(NOMINAL)
    return ({k: v for k, v in plant_parameters(cavity).items() if v != nominal[k]},
            cached_plant_envelope(cavity, tables))


def variant_config(overrides: dict, models_dir: str,
                   max_step: float) -> tuple[DLMPCConfig, dict, Path]:
    """A variant's ``(DLMPCConfig, run settings, models folder)``; the run settings are
    :class:`~dlmpc_ros.evaluation.runs.RunSpec` fields (``measurement_noise``,
    ``measurement_round_trips``)."""
    from dlmpc_ros.control.dlmpc_config import (AcquisitionConfig, DLMPCConfig, PlannerConfig,
                                               TrackingConfig)
    from dlmpc_ros.control.step import AngleLimits

    overrides = dict(overrides)
    run = {key: overrides.pop(key) for key in ('measurement_noise', 'measurement_round_trips')
           if key in overrides}  # run settings, not DLMPCConfig
    models = Path(os.path.expandvars(overrides.pop('models_dir', models_dir)))
    for key, kind in (('tracking', TrackingConfig), ('acquisition', AcquisitionConfig),
                      ('planner', PlannerConfig)):
        if isinstance(overrides.get(key), dict):  # from JSON: the config's fields
            overrides[key] = kind(**overrides[key])
    return DLMPCConfig(limits=AngleLimits(max_step=max_step), **overrides), run, models


def run_one(job: VariantRun) -> dict:
    """One closed-loop run of a variant."""
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.control.step import MODES
    from dlmpc_ros.evaluation.metrics import run_metrics
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast

    plant, envelope = plant_and_envelope(job.plant, Path(job.models_dir))
    if job.condition is None:
        spec = RunSpec(job.scenario, job.seed, 'dlmpc', round_trips=job.round_trips,
                       plant=plant)
    else:
        spec = RunSpec(job.condition['scenario'], job.seed, 'dlmpc',
                       settings=job.condition['settings'], round_trips=job.round_trips,
                       plant=plant, bench=job.condition['bench'], condition=job.scenario)
    config, run, models = variant_config(job.overrides, job.models_dir, spec.max_step)
    spec = replace(spec, **run)
    controller = load_dlmpc(models, config)
    started = time.monotonic()
    record = run_fast(spec, models, controller)
    metrics = run_metrics(record, envelope)
    modes = np.asarray(record.mode)
    return {'variant': job.variant, 'plant': job.plant, 'scenario': job.scenario,
            'seed': job.seed, 'wall_seconds': round(time.monotonic() - started, 1),
            'mode_fractions': {m: float(np.mean(modes == i)) for i, m in enumerate(MODES)
                               if np.any(modes == i)},
            **{k: metrics[k] for k in ('oracle_ratio', 'locked_fraction',
                                       'acquisition_round_trips', 'mean_O',
                                       'step_latency_ms_median')}}


def run_lock_block(job: LockBlock) -> dict:
    """A variant's cold starts (:func:`dlmpc_ros.evaluation.lock_benchmark.run_starts`)."""
    from dlmpc_ros.evaluation.lock_benchmark import LockSpec, LockTask, run_starts

    plant, envelope = plant_and_envelope(job.plant, Path(job.models_dir))
    spec = LockSpec('dlmpc', plant=plant)
    config, run, models = variant_config(job.overrides, job.models_dir, spec.max_step)
    if run:
        raise ValueError(f'the lock benchmark runs without run settings, got {run}')
    starts = run_starts(LockTask(spec, job.indices, str(models), envelope['K'],
                                 envelope['O_star'], config))
    return {'variant': job.variant, 'plant': job.plant, 'starts': starts}


def lock_table(blocks: list[dict]) -> tuple[str, dict]:
    """Markdown: variant x plant, starts locked (median control periods to lock), and the
    metrics per variant and plant."""
    from dlmpc_ros.evaluation.lock_benchmark import LockSpec, lock_metrics

    plants = list(dict.fromkeys(b['plant'] for b in blocks))
    summary: dict[str, dict[str, dict]] = {}
    for variant in dict.fromkeys(b['variant'] for b in blocks):
        for plant in plants:
            starts = sorted((s for b in blocks if b['variant'] == variant
                             and b['plant'] == plant for s in b['starts']),
                            key=lambda s: s['index'])
            summary.setdefault(variant, {})[plant] = lock_metrics(starts, LockSpec('dlmpc'))
    names = [p if p == 'nominal' else f'family-{p}' for p in plants]
    lines = ['| variant | ' + ' | '.join(names) + ' | locked | worst median periods |',
             '|---' * (len(plants) + 3) + '|']
    for variant, per_plant in summary.items():
        cells = [f"{m['locked']}/{m['starts']} ("
                 + (f"{m['median_control_periods']:.1f})" if m['locked'] else '-)')
                 for m in per_plant.values()]
        medians = [m['median_control_periods'] or np.inf for m in per_plant.values()]
        lines.append(f'| {variant} | ' + ' | '.join(cells) + ' | '
                     f"{sum(m['locked'] for m in per_plant.values())} | {max(medians):.1f} |")
    return '\n'.join(lines) + '\n', summary


def table(runs: list[dict], scenarios: list[str]) -> str:
    """Markdown: variant x (plant group, scenario), mean O / O* (min-max over runs)."""
    groups = [g for g in ('nominal', 'family') if any(
        (r['plant'] == 'nominal') == (g == 'nominal') for r in runs)]
    columns = [(g, s) for g in groups for s in scenarios]
    lines = ['| variant | ' + ' | '.join(
        f'{"nominal" if g == "nominal" else "family plants"} {s}' for g, s in columns)
        + ' | mean |', '|---' * (len(columns) + 2) + '|']
    for variant in dict.fromkeys(r['variant'] for r in runs):
        cells, means = [], []
        for group, scenario in columns:
            ratios = [r['oracle_ratio'] for r in runs if r['variant'] == variant
                      and r['scenario'] == scenario
                      and (r['plant'] == 'nominal') == (group == 'nominal')]
            means += ratios
            cells.append(f'{np.mean(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})'
                         if ratios else '')
        lines.append(f'| {variant} | ' + ' | '.join(cells) + f' | {np.mean(means):.3f} |')
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--variants', type=Path, required=True)
    p.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    p.add_argument('--scenario', action='append', choices=SCENARIOS,
                   help='repeatable (default: all four)')
    p.add_argument('--condition', action='append', default=[], metavar='NAME',
                   help='a stress suite condition (e.g. walk-servo6), repeatable, instead '
                        'of --scenario')
    p.add_argument('--nominal', action='store_true',
                   help='run the nominal cavity (the default without --plant-family)')
    p.add_argument('--plant-family', type=int, action='append', default=[], metavar='SEED')
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--out', type=Path, default=ROOT / 'bench/results/dlmpc_variants.json')
    p.add_argument('--workers', type=int, default=default_workers())
    p.add_argument('--lock-starts', type=int, default=0, metavar='N',
                   help='run the lock benchmark (N cold starts per plant, the seed-0 starts '
                        'of dlmpc-evaluate --benchmark lock) instead of the drift runs')
    args = p.parse_args(argv)
    variants = json.loads(args.variants.read_text())
    scenarios = args.scenario or list(SCENARIOS)
    plants = (['nominal'] if args.nominal or not args.plant_family else []) + \
        [str(s) for s in args.plant_family]
    for plant in plants:  # draws and envelopes once, here, before the runs share them
        plant_and_envelope(plant, args.models_dir)
    if args.lock_starts:
        return main_lock(args, variants, plants)
    conditions: dict[str, dict | None] = {scenario: None for scenario in scenarios}
    if args.condition:
        from dlmpc_ros.evaluation.suites import stress_conditions
        suite = stress_conditions()
        unknown = [c for c in args.condition if c not in suite]
        if unknown:
            p.error(f'unknown condition(s) {unknown}; one of {sorted(suite)}')
        conditions = {c: suite[c].to_dict() for c in args.condition}
        scenarios = list(conditions)
    jobs = [VariantRun(name, overrides, plant, scenario, seed, args.round_trips,
                       str(args.models_dir), condition)
            for name, overrides in variants.items() for plant in plants
            for scenario, condition in conditions.items() for seed in args.seeds]
    results = run_tasks(run_one, jobs, args.workers, desc='variant runs')
    failed = [r for r in results if isinstance(r, TaskFailure)]
    runs = [r for r in results if not isinstance(r, TaskFailure)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'variants': variants, 'seeds': args.seeds,
                                    'plants': plants, 'round_trips': args.round_trips,
                                    'failed': [str(f) for f in failed], 'runs': runs},
                                   indent=1))
    args.out.with_suffix('.md').write_text(table(runs, scenarios))
    print(table(runs, scenarios))
    return 1 if failed else 0


def main_lock(args: argparse.Namespace, variants: dict, plants: list[str]) -> int:
    """The lock benchmark of every variant on every plant, in blocks of 10 starts."""
    jobs = [LockBlock(name, overrides, plant,
                      tuple(range(first, min(first + 10, args.lock_starts))),
                      str(args.models_dir))
            for name, overrides in variants.items() for plant in plants
            for first in range(0, args.lock_starts, 10)]
    results = run_tasks(run_lock_block, jobs, args.workers, desc='lock blocks')
    failed = [r for r in results if isinstance(r, TaskFailure)]
    text, summary = lock_table([r for r in results if not isinstance(r, TaskFailure)])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'variants': variants, 'plants': plants,
                                    'lock_starts': args.lock_starts,
                                    'failed': [str(f) for f in failed], 'summary': summary},
                                   indent=1))
    args.out.with_suffix('.md').write_text(text)
    print(text)
    return 1 if failed else 0


if __name__ == '__main__':
    raise SystemExit(main())
