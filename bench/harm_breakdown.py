"""Where the DL-MPC loses to a held setting in the stress suite's do-no-harm misses.

For each DL-MPC run of a ``dlmpc-evaluate --suite stress`` output (with ``passive`` and
``fixed_best`` runs beside it) whose oracle ratio is more than 0.01 under the better of the
two, splits the mean O it lost to that setting (per round trip, held setting minus DL-MPC,
summed and divided by the run's round trips) by what the DL-MPC was doing: scanning for a
lock (``acquire``), tracking with its estimate on the side of 0 opposite to K while
|K| > 0.1 (on the branch meant for the other sign of K), or anything else. A diagnosis of
the runs, not a figure the controller is chosen on; it reads the true K from the records,
which no controller sees.

Usage::

    python bench/harm_breakdown.py OUT [OUT ...] [--margin 0.01]

Prints a Markdown table (``bench/results/harm_breakdown.md``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: The held settings a run is compared with.
HELD = ('passive', 'fixed_best')
#: |K| above which the side of 0 the estimate is on says which branch K wants.
SIDE_K = 0.1


def breakdown(out: Path, margin: float) -> list[dict]:
    """The do-no-harm misses of one stress output directory and where their O went."""
    from dlmpc_ros.control.step import MODES
    record = json.loads((out / 'metrics.json').read_text())
    runs = {(r['plant'], r['condition'], r['seed'], r['controller']): r for r in record['runs']}
    rows = []
    for (plant, condition, seed, controller), run in sorted(runs.items()):
        held = {k: runs.get((plant, condition, seed, k)) for k in HELD}
        if controller != 'dlmpc' or None in held.values():
            continue
        best = max(HELD, key=lambda k: held[k]['metrics']['oracle_ratio'])
        ratio, best_ratio = (run['metrics']['oracle_ratio'],
                             held[best]['metrics']['oracle_ratio'])
        if ratio >= best_ratio - margin:
            continue
        d = np.load(out / plant / f'{condition}-s{seed}-dlmpc' / 'record.npz')
        h = np.load(out / plant / f'{condition}-s{seed}-{best}' / 'record.npz')
        # the decision in force at each round trip
        at = np.clip(np.searchsorted(d['control_round_trip'], d['round_trip'], side='right') - 1,
                     0, None)
        mode, estimate = d['mode'][at], d['surrogate'][at]
        lost = h['O'] - d['O']
        scanning = mode == MODES.index('acquire')
        tracking = np.isin(mode, [MODES.index('track'), MODES.index('plan')])
        opposite = tracking & (np.abs(d['K']) > SIDE_K) & (np.sign(estimate) != np.sign(d['K']))
        n = len(lost)
        rows.append({'plant': plant, 'condition': condition, 'seed': seed, 'held': best,
                     'ratio': ratio, 'held_ratio': best_ratio,
                     'scanning': float(lost[scanning].sum() / n),
                     'opposite': float(lost[opposite].sum() / n),
                     'else': float(lost[~scanning & ~opposite].sum() / n),
                     'scanning_share': float(scanning.mean()),
                     'opposite_share': float(opposite.mean())})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('out', type=Path, nargs='+', help='dlmpc-evaluate --suite stress outputs')
    p.add_argument('--margin', type=float, default=0.01,
                   help='a miss: this far under the better held setting (oracle ratio)')
    args = p.parse_args(argv)
    rows = [row for out in args.out for row in breakdown(out, args.margin)]
    print('| plant | condition | seed | DL-MPC | better held | O lost while scanning | '
          'while tracking on the side opposite K | elsewhere | time scanning / opposite |')
    print('|---|---|---|---|---|---|---|---|---|')
    for r in rows:
        print(f"| {r['plant']} | {r['condition']} | {r['seed']} | {r['ratio']:.3f} | "
              f"{r['held_ratio']:.3f} ({r['held']}) | {r['scanning']:+.4f} | "
              f"{r['opposite']:+.4f} | {r['else']:+.4f} | {100 * r['scanning_share']:.1f} % / "
              f"{100 * r['opposite_share']:.1f} % |")
    if rows:
        total = {k: float(np.mean([r[k] for r in rows])) for k in ('scanning', 'opposite', 'else')}
        print(f"\nMean over the {len(rows)} misses: {total['scanning']:+.4f} while scanning, "
              f"{total['opposite']:+.4f} on the opposite side, {total['else']:+.4f} elsewhere "
              '(mean O per round trip).')
    return 0


if __name__ == '__main__':
    sys.exit(main())
