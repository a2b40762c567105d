"""The bench issue's table: DL-MPC with the emulated lab bench against its ideal-servo
runs, and against the baselines on the same bench (mean oracle ratio over seeds, per
plant and drift).

    dlmpc-evaluate --fast --round-trips 20000 --nominal --plant-family 101 ... \\
        --plant-family 108 --scenario sinusoidal --scenario random_walk \\
        --seed 1 --seed 2 --seed 3 --controller dlmpc --bench lab --workers 2 --out LAB
    (the same with --controller passive --controller fixed_best, and esc ga on seed 1)
    python bench/lab_bench.py --ideal docs/results/stress/kept-turn-no-wait/today/heldout-drift \\
        docs/results/stress/kept-turn-no-wait/today/nominal --lab LAB \\
        --baselines LAB_BASELINES LAB_SEARCHERS
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

PLANTS = ['nominal'] + [f'family-{p}' for p in range(101, 109)]
DRIFTS = ('sinusoidal', 'random_walk')
BASELINES = ('passive', 'fixed_best', 'esc', 'ga')


def metrics(folders: list[Path]) -> dict[tuple[str, str, int, str], dict]:
    """(plant, scenario, seed, controller) -> metrics of every run in ``folders`` (an
    output folder's ``metrics.json``, which holds all its runs, else those of its plant
    folders)."""
    out = {}
    for folder in folders:
        top = folder / 'metrics.json'
        sources = [(None, top)] if top.exists() else [
            (p, folder / p / 'metrics.json') for p in PLANTS]
        for plant, path in sources:
            if not path.exists():
                continue
            data = json.loads(path.read_text())
            for run in data['runs']:
                where = plant or run.get('plant', data.get('plant', 'nominal'))
                out[(where, run['scenario'], run['seed'], run['controller'])] = run['metrics']
    return out


def ratios(runs: dict, yardstick: dict) -> dict[tuple[str, str, int, str], float]:
    """Mean O over the mean O*(K(t)) of the same plant, drift and seed in ``yardstick``
    (the lab runs: K(t) is the same on both benches, so both sides divide by the same
    envelope, whichever version of it each was recorded with); the run's own ratio where
    the yardstick has no such run."""
    oracle = {k[:3]: m['mean_oracle_O'] for k, m in yardstick.items()}
    return {k: m['mean_O'] / oracle[k[:3]] if k[:3] in oracle else m['oracle_ratio']
            for k, m in runs.items()}


def mean_over_seeds(runs: dict, plant: str, drift: str, controller: str) -> float | None:
    values = [v for (p, d, _, c), v in runs.items()
              if (p, d, c) == (plant, drift, controller)]
    return float(np.mean(values)) if values else None


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--ideal', type=Path, nargs='+', required=True)
    p.add_argument('--lab', type=Path, nargs='+', required=True)
    p.add_argument('--baselines', type=Path, nargs='*', default=[])
    args = p.parse_args()
    lab_runs = metrics(args.lab)
    ideal, lab = ratios(metrics(args.ideal), lab_runs), ratios(lab_runs, lab_runs)
    base = ratios(metrics(args.baselines), lab_runs)
    print('| plant | drift | DL-MPC ideal | DL-MPC lab | lab - ideal | best baseline on the '
          'lab bench |')
    print('|---|---|---|---|---|---|')
    changes, margins = [], []
    for plant in PLANTS:
        for drift in DRIFTS:
            before = mean_over_seeds(ideal, plant, drift, 'dlmpc')
            after = mean_over_seeds(lab, plant, drift, 'dlmpc')
            if before is None or after is None:
                continue
            changes.append(after - before)
            scored = {c: mean_over_seeds(base, plant, drift, c) for c in BASELINES}
            scored = {c: v for c, v in scored.items() if v is not None}
            best = max(scored, key=scored.get) if scored else None
            if best is not None:
                margins.append(after - scored[best])
            shown = f'{scored[best]:.3f} ({best})' if best else '-'
            print(f'| {plant} | {drift} | {before:.3f} | {after:.3f} | {after - before:+.3f} '
                  f'| {shown} |')
    held = [k for k in lab if k[0] != 'nominal' and k[3] == 'dlmpc' and k in ideal]
    print(f'\nlab - ideal: mean {np.mean(changes):+.4f}, worst {min(changes):+.4f} '
          f'({len(changes)} plant x drift cells); held-out 101-108: lab '
          f'{np.mean([lab[k] for k in held]):.4f}, ideal {np.mean([ideal[k] for k in held]):.4f}')
    if margins:
        print(f'DL-MPC on the lab bench above the best baseline on it in '
              f'{sum(m > 0 for m in margins)} of {len(margins)} cells (closest '
              f'{min(margins):+.4f})')


if __name__ == '__main__':
    main()
