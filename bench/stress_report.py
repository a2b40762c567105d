"""The stress suite before and after a controller change, with issue 32's targets checked.

Per plant x condition x seed: the DL-MPC before and after, passive and fixed_best, as mean
O over the mean O*(K(t)) of the *after* runs (the same K(t) in both; the envelopes as the
after runs computed them, so runs recorded with an older envelope compare on today's);
then the mean over plants per condition, the runs more than 0.01 below the better of
passive and fixed_best (do no harm), and the share of control periods in each mode.

    python bench/stress_report.py --before docs/results/stress/before/metrics.json \\
        --after docs/results/stress/after/development/metrics.json \\
        --title "Stress suite, development plants" --out REPORT.md

``--before`` and ``--after`` take ``metrics.json`` files of ``dlmpc-evaluate --suite
stress`` (repeatable); a baseline missing from ``--after`` is read from ``--before``.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

BASELINES = ('passive', 'fixed_best')


def suite_runs(paths: list[Path]) -> dict[tuple[str, str, int, str], dict]:
    """(plant, condition, seed, controller) -> the run's metrics."""
    out = {}
    for path in paths:
        for run in json.loads(Path(path).read_text())['runs']:
            key = (run.get('plant', 'nominal'), run['meta'].get('condition'), run['seed'],
                   run['controller'])
            out[key] = run['metrics']
    return out


def report(before: dict, after: dict, title: str) -> str:
    oracle = {k[:3]: m['mean_oracle_O'] for k, m in after.items()}

    def ratio(plant: str, cond: str, seed: int, ctrl: str, tables) -> float | None:
        for table in tables:
            m = table.get((plant, cond, seed, ctrl))
            if m is not None and (plant, cond, seed) in oracle:
                return m['mean_O'] / oracle[(plant, cond, seed)]
        return None

    def text(x: float | None) -> str:
        return '-' if x is None else f'{x:.3f}'

    cells = sorted(oracle, key=lambda k: (k[0] != 'nominal', k[0], k[1], k[2]))
    lines = [f'# {title}', '', '| plant | condition | seed | DL-MPC before | DL-MPC after | '
             'passive | fixed_best | after - better baseline |',
             '|---|---|---|---|---|---|---|---|']
    harm, per_condition = [], defaultdict(list)
    # plant x condition cells: the DL-MPC after against every other controller in the
    # tables, each as its mean over the cell's seeds
    others = sorted({k[3] for k in (*after, *before) if k[3] != 'dlmpc'})
    cell_means = defaultdict(lambda: defaultdict(list))  # (plant, cond) -> ctrl -> ratios
    for plant, cond, seed in cells:
        old = ratio(plant, cond, seed, 'dlmpc', [before])
        new = ratio(plant, cond, seed, 'dlmpc', [after])
        base = [ratio(plant, cond, seed, b, [after, before]) for b in BASELINES]
        known = [b for b in base if b is not None]
        margin = None if new is None or not known else new - max(known)
        if margin is not None and margin < -0.01:
            harm.append(f'{plant} {cond} seed {seed} {new:.3f} against {max(known):.3f}')
        per_condition[cond].append((old, new, *base))
        found = {'dlmpc': new, **dict(zip(BASELINES, base)),
                 **{c: ratio(plant, cond, seed, c, [after, before])
                    for c in others if c not in BASELINES}}
        for ctrl, value in found.items():
            if value is not None:
                cell_means[(plant, cond)][ctrl].append(value)
        lines.append(f'| {plant} | {cond} | {seed} | {text(old)} | {text(new)} | '
                     f'{text(base[0])} | {text(base[1])} | '
                     f'{"-" if margin is None else f"{margin:+.3f}"} |')
    lines += ['', 'Mean over plants per condition:', '',
              '| condition | DL-MPC before | DL-MPC after | passive | fixed_best |',
              '|---|---|---|---|---|']
    for cond in sorted(per_condition):
        means = []
        for i in range(4):
            values = [r[i] for r in per_condition[cond] if r[i] is not None]
            means.append(f'{np.mean(values):.3f}' if values else '-')
        lines.append(f'| {cond} | ' + ' | '.join(means) + ' |')
    olds = [r[0] for rows in per_condition.values() for r in rows if r[0] is not None]
    news = [r[1] for rows in per_condition.values() for r in rows if r[1] is not None]
    compared = {cell: runs for cell, runs in cell_means.items() if 'dlmpc' in runs}
    above = sum(np.mean(runs['dlmpc']) > max(np.mean(runs[c]) for c in runs if c != 'dlmpc')
                for runs in compared.values() if len(runs) > 1)
    lines += ['', f'All runs: DL-MPC before {np.mean(olds) if olds else float("nan"):.3f} '
              f'({len(olds)} runs), after {np.mean(news):.3f} ({len(news)} runs).', '',
              f'Plant x condition cells (each controller\'s mean over the seeds it ran) where '
              f'the DL-MPC after is above every other controller ({", ".join(others)}): '
              f'{above} of {len(compared)}.', '',
              f'Runs more than 0.01 below the better of passive and fixed_best: {len(harm)}'
              + (': ' + '; '.join(harm) if harm else '') + '.', '']
    for name, table in (('before', before), ('after', after)):
        shares, runs = defaultdict(float), 0
        for key, m in table.items():
            if key[3] == 'dlmpc' and key[:3] in oracle:
                runs += 1
                for mode, share in (m.get('mode_fractions') or {}).items():
                    shares[mode] += share
        if runs:
            lines.append(f'Mode shares {name} (mean over {runs} DL-MPC runs): ' + ', '.join(
                f'{mode} {100 * total / runs:.2f} %' for mode, total in sorted(shares.items()))
                + '.')
    return '\n'.join(lines) + '\n'


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--before', type=Path, action='append', default=[])
    p.add_argument('--after', type=Path, action='append', required=True)
    p.add_argument('--title', default='Stress suite')
    p.add_argument('--out', type=Path)
    args = p.parse_args()
    text = report(suite_runs(args.before), suite_runs(args.after), args.title)
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == '__main__':
    main()
