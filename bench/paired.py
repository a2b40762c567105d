"""Paired difference of two records of the same runs before and after a change.

A record is a ``dlmpc-evaluate`` ``metrics.json`` or a ``bench/dlmpc_variants.py`` output
(one variant of it: ``--before-variant``, ``--after-variant``), or sections of a JSON
file holding several, ``PATH:KEY[.KEY...][,...]`` (e.g. the shipped controller's
development runs, ``bench/results/tracker_guard.json:development_entry_only.seed1``).

Runs are paired by plant, scenario (or stress condition), seed and controller (a variant's
runs are the DL-MPC's); the figure is each run's ``oracle_ratio`` (mean O over its plant's
envelope) unless ``--metric`` names another. Prints the mean of each side, the mean
difference (after minus before) with a bootstrap 90 % interval over the paired runs
(seeded, so the same records give the same interval), and how many runs moved by more than
``--by`` either way; runs that are in only one record are counted and left out. With
``--split``, the same per drift (a stress condition's part before its ``-``) and per plant.

Usage::

    python bench/paired.py BEFORE/metrics.json AFTER/metrics.json [--controller dlmpc]
        [--metric oracle_ratio] [--by 0.005]
    python bench/paired.py bench/results/tracker_guard.json:development_entry_only.seed1 \
        bench/results/turn_step.json --after-variant "turn step 0.1" --split
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: Bootstrap resamples of the mean difference.
RESAMPLES = 10_000
#: ``--split``'s groups of a run key ``(plant, condition or scenario, seed, controller)``:
#: the drift (a stress condition's part before its ``-``) and the plant.
SPLITS = {'drift': lambda key: key[1].split('-')[0], 'plant': lambda key: key[0]}


def load_record(spec: str) -> list[dict]:
    """The runs of the record at ``PATH``, or of its sections ``PATH:KEY[.KEY...][,...]``
    (several sections: their runs together)."""
    path, _, sections = spec.partition(':') if not Path(spec).exists() else (spec, '', '')
    whole = json.loads(Path(path).read_text())
    out = []
    for section in sections.split(',') if sections else ['']:
        record = whole
        for key in filter(None, section.split('.')):
            if not isinstance(record, dict) or key not in record:
                raise ValueError(f'{path} has no section {section!r} (at {key!r})')
            record = record[key]
        out += record['runs'] if isinstance(record, dict) else record
    return out


def runs(record: list[dict], controller: str | None, metric: str,
         variant: str | None = None) -> dict[tuple, float]:
    """``(plant, stress condition or scenario, seed, controller) -> metric`` of a record's
    runs (of ``variant`` only, where given, in a ``dlmpc_variants.py`` record)."""
    names = {run['variant'] for run in record if 'variant' in run}
    if variant is None and len(names) > 1:
        raise ValueError(f'the record holds the variants {sorted(names)}: choose one')
    out = {}
    for run in record:
        if 'variant' in run:  # dlmpc_variants.py: the DL-MPC's runs, the figures at top level
            if variant is not None and run['variant'] != variant:
                continue
            plant, who, value = str(run['plant']), 'dlmpc', run.get(metric)
            plant = f'family-{plant}' if plant.isdigit() else plant
        else:
            plant, who, value = run['plant'], run['controller'], run['metrics'].get(metric)
        if controller is not None and who != controller:
            continue
        if value is not None:
            out[(plant, run.get('condition') or run['scenario'], int(run['seed']), who)] = \
                float(value)
    return out


def paired(before: dict[tuple, float], after: dict[tuple, float],
           seed: int = 0) -> dict[str, float]:
    """Means, mean difference and its bootstrap 90 % interval over the shared runs."""
    keys = sorted(set(before) & set(after))
    if not keys:
        raise ValueError('the two records share no run')
    b = np.array([before[k] for k in keys])
    a = np.array([after[k] for k in keys])
    diff = a - b
    rng = np.random.default_rng(seed)
    means = diff[rng.integers(diff.size, size=(RESAMPLES, diff.size))].mean(axis=1)
    low, high = np.quantile(means, [0.05, 0.95])
    return {'runs': len(keys), 'before': float(b.mean()), 'after': float(a.mean()),
            'difference': float(diff.mean()), 'low': float(low), 'high': float(high),
            'identical': int(np.sum(diff == 0)), 'diff': diff,
            'only_before': len(set(before) - set(after)),
            'only_after': len(set(after) - set(before))}


def line(result: dict, by: float) -> str:
    """One summary of :func:`paired`'s result."""
    diff = result['diff']
    return (f"{result['runs']} paired runs: before {result['before']:.4f}, after "
            f"{result['after']:.4f}, difference {result['difference']:+.4f} (90 % interval "
            f"{result['low']:+.4f} to {result['high']:+.4f}); {result['identical']} "
            f"identical, {int(np.sum(diff > by))} better and {int(np.sum(diff < -by))} worse "
            f"by more than {by}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('before', help='PATH or PATH:KEY[.KEY...]')
    parser.add_argument('after', help='PATH or PATH:KEY[.KEY...]')
    parser.add_argument('--controller', default='dlmpc', help="'all': every controller")
    parser.add_argument('--before-variant', help='of a dlmpc_variants.py record')
    parser.add_argument('--after-variant', help='of a dlmpc_variants.py record')
    parser.add_argument('--metric', default='oracle_ratio')
    parser.add_argument('--by', type=float, default=0.005,
                        help='a run counts as better or worse beyond this difference')
    parser.add_argument('--split', action='store_true', help='also per drift and per plant')
    args = parser.parse_args()
    controller = None if args.controller == 'all' else args.controller
    try:
        before = runs(load_record(args.before), controller, args.metric, args.before_variant)
        after = runs(load_record(args.after), controller, args.metric, args.after_variant)
        result = paired(before, after)
    except (OSError, ValueError) as error:
        parser.error(str(error))
    print(f"{args.metric}, {args.controller}: {line(result, args.by)}; only before "
          f"{result['only_before']}, only after {result['only_after']}")
    if args.split:
        for name, group_of in SPLITS.items():
            for group in sorted({group_of(k) for k in set(before) & set(after)}):
                part = paired({k: v for k, v in before.items() if group_of(k) == group},
                              {k: v for k, v in after.items() if group_of(k) == group})
                print(f"  {name} {group}: {line(part, args.by)}")


if __name__ == '__main__':
    main()
