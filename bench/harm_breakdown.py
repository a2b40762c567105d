"""Where the DL-MPC loses to a held setting in the stress suite's do-no-harm misses.

For each DL-MPC run of a ``dlmpc-evaluate --suite stress`` output (with ``passive`` and
``fixed_best`` runs beside it) whose oracle ratio is more than 0.01 under the better of the
two, splits the mean O it lost to that setting (per round trip, held setting minus DL-MPC,
summed and divided by the run's round trips) by what the DL-MPC was doing: scanning for a
lock (``acquire``), tracking with its estimate on the side of 0 opposite to K while
|K| > 0.1 (on the branch meant for the other sign of K), or anything else. A diagnosis of
the runs, not a figure the controller is chosen on; it reads the true K from the records,
which no controller sees.

With ``--envelope``, every DL-MPC run of the outputs instead (``--condition`` to pick some),
against its plant's envelope O*(K): the share of the envelope it lost in each of the same
parts, the 500 round trips after a step of K apart (they add up to 1 - the run's oracle
ratio; ``bench/results/envelope_breakdown.md``).

Usage::

    python bench/harm_breakdown.py OUT [OUT ...] [--margin 0.01]
    python bench/harm_breakdown.py OUT [OUT ...] --envelope [--condition steps-ideal ...]

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
#: ``--envelope``: round trips after a step of K counted apart (a tenth of a steps period).
AFTER_JUMP = 500


def _parts(d, lost: np.ndarray, n: float, after_jump: int = 0) -> dict:
    """O ``lost`` (per round trip of record ``d``) while scanning, while tracking on the side
    of 0 opposite to K, and elsewhere, each summed and divided by ``n``; and the shares of
    time scanning and opposite. With ``after_jump``, elsewhere within that many round trips
    after K jumped by more than ``SIDE_K`` in one round trip (a step) is a part of its own."""
    from dlmpc_ros.control.step import MODES
    # the decision in force at each round trip
    at = np.clip(np.searchsorted(d['control_round_trip'], d['round_trip'], side='right') - 1,
                 0, None)
    mode, estimate = d['mode'][at], d['surrogate'][at]
    scanning = mode == MODES.index('acquire')
    tracking = np.isin(mode, [MODES.index('track'), MODES.index('plan')])
    opposite = tracking & (np.abs(d['K']) > SIDE_K) & (np.sign(estimate) != np.sign(d['K']))
    jumps = np.flatnonzero(np.abs(np.diff(d['K'])) > SIDE_K) + 1
    since = np.full(len(lost), np.inf)
    for j in jumps:
        since[j:] = np.arange(len(lost) - j)
    settling = (since < after_jump) & ~scanning & ~opposite
    parts = {'scanning': float(lost[scanning].sum() / n),
             'opposite': float(lost[opposite].sum() / n),
             'else': float(lost[~scanning & ~opposite & ~settling].sum() / n),
             'scanning_share': float(scanning.mean()),
             'opposite_share': float(opposite.mean())}
    if after_jump:
        parts['after_jump'] = float(lost[settling].sum() / n)
    return parts


def envelope_breakdown(out: Path, conditions: list[str]) -> list[dict]:
    """Every DL-MPC run of one stress output (of ``conditions``; empty: all) and the share
    of its plant's envelope it lost in each part (:func:`_parts`)."""
    sys.path.insert(0, str(ROOT / 'bench'))
    from dlmpc_variants import plant_and_envelope
    from dlmpc_ros.learning.tables import envelope_objective
    record = json.loads((out / 'metrics.json').read_text())
    rows, envelopes = [], {}
    for run in record['runs']:
        plant, condition, seed = run['plant'], run['condition'], run['seed']
        if run['controller'] != 'dlmpc' or (conditions and condition not in conditions):
            continue
        if plant not in envelopes:
            envelopes[plant] = plant_and_envelope(plant.removeprefix('family-'),
                                                  ROOT / 'models')[1]
        d = np.load(out / plant / f'{condition}-s{seed}-dlmpc' / 'record.npz')
        best = envelope_objective(envelopes[plant], d['K'])
        rows.append({'plant': plant, 'condition': condition, 'seed': seed,
                     'ratio': run['metrics']['oracle_ratio'],
                     **_parts(d, best - d['O'], float(best.sum()), AFTER_JUMP)})
    return rows


def breakdown(out: Path, margin: float) -> list[dict]:
    """The do-no-harm misses of one stress output directory and where their O went."""
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
        rows.append({'plant': plant, 'condition': condition, 'seed': seed, 'held': best,
                     'ratio': ratio, 'held_ratio': best_ratio,
                     **_parts(d, h['O'] - d['O'], float(len(d['O'])))})
    return rows


def print_envelope(rows: list[dict]) -> None:
    """The ``--envelope`` table: each run, then the mean per condition and over all."""
    print('| plant | condition | seed | DL-MPC | envelope lost while scanning | while tracking '
          f'on the side opposite K | elsewhere, {AFTER_JUMP} round trips after a step of K '
          '| elsewhere | time scanning / opposite |')
    print('|---|---|---|---|---|---|---|---|---|')
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(r['condition'], []).append(r)
        groups.setdefault('all', []).append(r)
    lines = [(r['plant'], r['condition'], str(r['seed']), r) for r in rows]
    lines += [('mean', name, f'{len(g)} runs', {k: float(np.mean([r[k] for r in g]))
                                                for k in g[0] if isinstance(g[0][k], float)})
              for name, g in groups.items()]
    for plant, condition, seed, r in lines:
        print(f"| {plant} | {condition} | {seed} | {r['ratio']:.3f} | {r['scanning']:.4f} | "
              f"{r['opposite']:.4f} | {r['after_jump']:.4f} | {r['else']:.4f} | "
              f"{100 * r['scanning_share']:.1f} % / "
              f"{100 * r['opposite_share']:.1f} % |")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('out', type=Path, nargs='+', help='dlmpc-evaluate --suite stress outputs')
    p.add_argument('--margin', type=float, default=0.01,
                   help='a miss: this far under the better held setting (oracle ratio)')
    p.add_argument('--envelope', action='store_true',
                   help="every DL-MPC run against its plant's envelope, not the misses")
    p.add_argument('--condition', action='append', default=[],
                   help='with --envelope: only this stress condition (repeatable)')
    args = p.parse_args(argv)
    if args.envelope:
        print_envelope([row for out in args.out for row in envelope_breakdown(
            out, args.condition)])
        return 0
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
