"""Benchmark suites: named tables of conditions (a drift scenario with its settings on a
bench) that ``dlmpc-evaluate --suite NAME`` runs for every controller, seed and plant,
and the suite's table, ``OUT/stress.md`` and ``OUT/stress.json``.

The ``stress`` suite is what a lab brings (issue 32): the whole K range [-0.3, 0.3]
(sinusoids of amplitude 0.3 at periods 6,000 and 20,000 round trips, a random walk that
reaches +-0.3 within 20,000 round trips, steps between -0.3 and +0.3), each with ideal
servos, servos with lag and a slew limit (3 round trips and 0.1 rad per round trip; 6 and
0.04: the bench presets ``servo-3`` and ``servo-6``) and ideal servos with 1 % detector
noise. Its lock part (cold starts with K held at +0.3 and at -0.3) is the lock benchmark
with ``--lock-k``.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dlmpc_ros.core.bench import BENCH_PRESETS, BenchConfig
from dlmpc_ros.evaluation.presets import PRESETS, preset_settings
from dlmpc_ros.evaluation.report import run_case

#: A run above this share of its plant's envelope means the envelope search missed an
#: optimum of that plant (every ratio on it is inflated).
ENVELOPE_BOUND = 1.0


@dataclass(frozen=True)
class Condition:
    """One condition of a suite: a drift scenario preset with its settings, on a bench."""

    name: str
    """Label of the condition (also names its runs' folders: letters, digits, ``-``)."""
    scenario: str
    """Drift preset (:data:`~dlmpc_ros.evaluation.presets.PRESETS`)."""
    settings: dict = field(default_factory=dict)
    """The scenario's settings (the preset's, overridden by these)."""
    bench: dict = field(default_factory=dict)
    """The bench's settings that differ from an ideal one
    (:class:`~dlmpc_ros.core.bench.BenchConfig`)."""

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c == '-' for c in self.name):
            raise ValueError(f'Condition.name must be letters, digits and -, got {self.name!r}')
        if self.scenario not in PRESETS:
            raise ValueError(f'Condition.scenario must be one of {tuple(PRESETS)}, '
                             f'got {self.scenario!r}')
        object.__setattr__(self, 'settings', preset_settings(self.scenario, self.settings))
        # raises on a bad setting
        object.__setattr__(self, 'bench', BenchConfig(**self.bench).changes())

    def to_dict(self) -> dict:
        return {'scenario': self.scenario, 'settings': dict(self.settings),
                'bench': dict(self.bench)}


#: The stress suite's drifts: label -> (scenario preset, its settings). The random walk's
#: sigma 0.25 and correlation time 2,000 round trips take K to both ends of [-0.3, 0.3]
#: within 20,000 round trips for seeds 1-3 (test_suites checks it).
STRESS_DRIFTS: dict[str, tuple[str, dict]] = {
    'sin6k': ('sinusoidal', {'amplitude': 0.3, 'period': 6000.0}),
    'sin20k': ('sinusoidal', {'amplitude': 0.3, 'period': 20000.0}),
    'walk': ('random_walk', {'sigma': 0.25, 'correlation_time': 2000.0}),
    'steps': ('steps', {'offset': -0.3, 'times': [5000.0, 10000.0, 15000.0],
                        'values': [0.3, -0.3, 0.3]}),
}
#: The stress suite's benches: label -> bench settings. ``noise1``: ideal servos with 1 %
#: detector noise on E and M (the noise alone; the ``lab`` bench preset adds it to
#: ``servo-6``).
STRESS_BENCHES: dict[str, dict] = {
    'ideal': {},
    'servo3': dict(BENCH_PRESETS['servo-3']),
    'servo6': dict(BENCH_PRESETS['servo-6']),
    'noise1': {'detector_noise': 0.01},
}


def stress_conditions() -> dict[str, Condition]:
    """The stress suite: every drift on every bench, named ``DRIFT-BENCH``."""
    return {f'{d}-{b}': Condition(f'{d}-{b}', scenario, settings, bench)
            for (d, (scenario, settings)), (b, bench)
            in itertools.product(STRESS_DRIFTS.items(), STRESS_BENCHES.items())}


#: Suites by name: conditions, and the seeds and controllers they run by default.
SUITES = {'stress': stress_conditions}
SUITE_SEEDS = {'stress': (1, 2, 3)}
SUITE_CONTROLLERS = {'stress': ('dlmpc', 'esc', 'ga', 'passive', 'fixed_best')}
#: The lock part of the stress suite: K held at these values (``--lock-k``).
STRESS_LOCK_K = (0.3, -0.3)


def over_envelope(runs: list[dict]) -> list[dict]:
    """The runs whose oracle ratio exceeds :data:`ENVELOPE_BOUND`: plant, condition, seed,
    controller, ratio."""
    return [{'plant': r.get('plant', 'nominal'), 'condition': run_case(r), 'seed': r['seed'],
             'controller': r['controller'], 'oracle_ratio': r['metrics']['oracle_ratio']}
            for r in runs if (r['metrics'].get('oracle_ratio') or 0.0) > ENVELOPE_BOUND]


def over_envelope_warning(run: dict) -> str:
    """One line for a run of :func:`over_envelope`."""
    return (f"warning: {run['plant']} {run['condition']} seed {run['seed']} "
            f"{run['controller']}: oracle ratio {run['oracle_ratio']:.3f} > "
            f"{ENVELOPE_BOUND:.1f}: the envelope search missed this plant's optimum")


def suite_cells(runs: list[dict]) -> list[dict]:
    """Per plant x condition x controller (in run order): mean, min and max of the oracle
    ratio over seeds and how many seeds."""
    groups: dict[tuple, list[float]] = {}
    for r in runs:
        key = (r.get('plant', 'nominal'), run_case(r), r['controller'])
        value = r['metrics'].get('oracle_ratio')
        groups.setdefault(key, [])
        if value is not None:
            groups[key].append(float(value))
    return [{'plant': p, 'condition': c, 'controller': k, 'seeds': len(v),
             'mean': float(np.mean(v)) if v else None, 'min': min(v) if v else None,
             'max': max(v) if v else None} for (p, c, k), v in groups.items()]


def suite_markdown(name: str, cells: list[dict], over: list[dict], heading: str) -> str:
    """The suite's table: per plant, condition (rows) x controller (columns), the mean
    oracle ratio over seeds (min-max); then the mean over plants; then the runs above the
    envelope."""
    controllers = list(dict.fromkeys(c['controller'] for c in cells))
    plants = list(dict.fromkeys(c['plant'] for c in cells))
    lookup = {(c['plant'], c['condition'], c['controller']): c for c in cells}
    lines = [f'# {name} suite', '', heading, '']

    def table(plant_rows: list[tuple[str, str]], values) -> None:
        lines.extend(['| plant | condition | ' + ' | '.join(controllers) + ' |',
                      '|---|---|' + '---|' * len(controllers)])
        for plant, condition in plant_rows:
            lines.append(f'| {plant} | {condition} | '
                         + ' | '.join(values(plant, condition, k) for k in controllers) + ' |')
        lines.append('')

    def cell(plant: str, condition: str, controller: str) -> str:
        c = lookup.get((plant, condition, controller))
        if c is None or c['mean'] is None:
            return '-'
        text = f"{c['mean']:.3f}"
        return text if c['seeds'] == 1 else f"{text} ({c['min']:.3f}-{c['max']:.3f})"

    rows = list(dict.fromkeys((c['plant'], c['condition']) for c in cells))
    table(rows, cell)
    if len(plants) > 1:
        lines += ['Mean over the plants (of each plant\'s mean over seeds):', '']

        def mean(_: str, condition: str, controller: str) -> str:
            values = [c['mean'] for c in cells if c['condition'] == condition
                      and c['controller'] == controller and c['mean'] is not None]
            return f'{np.mean(values):.3f}' if values else '-'
        table([('all', c) for c in dict.fromkeys(c['condition'] for c in cells)], mean)
    if over:
        lines += [f'Runs above {ENVELOPE_BOUND:.1f} of their plant\'s envelope (the envelope '
                  'search missed this plant\'s optimum; every ratio on it is inflated):', '',
                  '| plant | condition | seed | controller | oracle ratio |',
                  '|---|---|---|---|---|']
        lines += [f"| {r['plant']} | {r['condition']} | {r['seed']} | {r['controller']} | "
                  f"{r['oracle_ratio']:.3f} |" for r in over]
    else:
        lines.append(f'No run exceeds {ENVELOPE_BOUND:.1f} of its plant\'s envelope.')
    return '\n'.join(lines) + '\n'


def write_suite(out: Path, name: str, conditions: dict[str, Condition], runs: list[dict],
                plants: dict[str, dict], settings: dict) -> list[dict]:
    """``OUT/NAME.md`` and ``OUT/NAME.json`` of a suite's runs; the runs above the
    envelope. ``settings``: what else the suite ran with (round trips, seeds, ...)."""
    cells = suite_cells(runs)
    over = over_envelope(runs)
    seeds = list(settings.get('seeds', []))
    over_seeds = (f"seed {seeds[0]}" if len(seeds) == 1 else
                  f"mean over seeds {', '.join(str(s) for s in seeds)} (min-max)")
    heading = (f"oracle_ratio (mean O / mean O*(K), each plant's own envelope), {over_seeds}, "
               f"{settings.get('round_trips')} round trips per run, fast mode.")
    listing = '\n'.join(f'- {c.name}: {c.scenario} {json.dumps(c.settings)}, '
                        + (f'bench {json.dumps(c.bench)}' if c.bench else 'ideal bench')
                        for c in conditions.values())
    (out / f'{name}.md').write_text(suite_markdown(name, cells, over, heading)
                                    + f'\nConditions:\n\n{listing}\n')
    (out / f'{name}.json').write_text(json.dumps({
        'suite': name, 'settings': settings, 'plants': plants,
        'conditions': {k: c.to_dict() for k, c in conditions.items()},
        'cells': cells, 'over_envelope': over,
        'runs': [{'plant': r.get('plant', 'nominal'), 'condition': run_case(r),
                  'seed': r['seed'], 'controller': r['controller'],
                  'oracle_ratio': r['metrics'].get('oracle_ratio'),
                  'locked_fraction': r['metrics'].get('locked_fraction'),
                  'acquisition_round_trips': r['metrics'].get('acquisition_round_trips'),
                  'mode_fractions': r['metrics'].get('mode_fractions')} for r in runs]},
        indent=1))
    return over
