"""Paired difference of two ``dlmpc-evaluate`` records: the same runs before and after a change.

Runs are paired by plant, scenario (or stress condition), seed and controller; the figure is
each run's ``oracle_ratio`` (mean O over its plant's envelope) unless ``--metric`` names
another. Prints the mean of each side, the mean difference (after minus before) with a
bootstrap 90 % interval over the paired runs (seeded, so the same records give the same
interval), and how many runs moved by more than ``--by`` either way; runs that are in only
one record are counted and left out.

Usage::

    python bench/paired.py BEFORE/metrics.json AFTER/metrics.json [--controller dlmpc]
        [--metric oracle_ratio] [--by 0.005]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: Bootstrap resamples of the mean difference.
RESAMPLES = 10_000


def runs(path: Path, controller: str | None, metric: str) -> dict[tuple, float]:
    """``(plant, stress condition or scenario, seed, controller) -> metric`` of a record's
    runs."""
    record = json.loads(path.read_text())
    out = {}
    for run in record['runs'] if isinstance(record, dict) else record:
        if controller is not None and run['controller'] != controller:
            continue
        value = run['metrics'].get(metric)
        if value is not None:
            out[(run['plant'], run.get('condition') or run['scenario'], int(run['seed']),
                 run['controller'])] = float(value)
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('before', type=Path)
    parser.add_argument('after', type=Path)
    parser.add_argument('--controller', default='dlmpc', help="'all': every controller")
    parser.add_argument('--metric', default='oracle_ratio')
    parser.add_argument('--by', type=float, default=0.005,
                        help='a run counts as better or worse beyond this difference')
    args = parser.parse_args()
    controller = None if args.controller == 'all' else args.controller
    result = paired(runs(args.before, controller, args.metric),
                    runs(args.after, controller, args.metric))
    diff = result.pop('diff')
    print(f"{result['runs']} paired runs ({args.metric}, {args.controller}): before "
          f"{result['before']:.4f}, after {result['after']:.4f}, difference "
          f"{result['difference']:+.4f} (90 % interval {result['low']:+.4f} to "
          f"{result['high']:+.4f}); {result['identical']} identical, "
          f"{int(np.sum(diff > args.by))} better and {int(np.sum(diff < -args.by))} worse "
          f"by more than {args.by}; only before {result['only_before']}, only after "
          f"{result['only_after']}")


if __name__ == '__main__':
    main()
