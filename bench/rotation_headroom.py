"""How much can turning the curve (the MPC step's action) add on a plant at all?

The DL-MPC's model-predictive step chooses one thing: the rotation theta of the tracking
curve at the point the tracker is at (:mod:`dlmpc_ros.control.rotation_planner`). Its
ceiling on a plant is what the best rotation gives over rotation 0 there. For each plant
(the nominal cavity, development plants 1-8, held-out plants 101-108: the plants of
``dlmpc-evaluate --plant-family``, drawn the same way), at each K of ``--k`` (the curve's
good side; the mirror twin serves -K alike) and each curve point ``u = K + offset``, the
laser settles at the curve point and the rotation is stepped away from 0 both ways,
carrying its pulse (the rotation data's own scan, :func:`dlmpc_ros.training.response.
plant_rows`). Reported per plant, as a fraction of the plant's own envelope O*(K) (the
benchmark's unit), averaged over K:

- ``curve``: O at rotation 0 (at the best of the offsets);
- ``best rotation``: O at the best rotation (same offsets);
- ``headroom``: their difference, the most a perfect rotation planner adds on a drift
  that spends equal time at each |K| of the grid (it reads the true K: a bound for the
  ablation, never a controller).

::

    python bench/rotation_headroom.py --out bench/results/rotation_headroom.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.scaleout import default_workers, run_tasks

ROOT = Path(__file__).resolve().parents[1]
DEVELOPMENT = tuple(range(1, 9))
HELD_OUT = tuple(range(101, 109))


def plant_headroom(job: tuple[int, tuple[float, ...], tuple[float, ...]]) -> dict:
    """The rotation scan of one plant (family seed, 0: the nominal cavity) and its
    envelope at the scan's K."""
    from dlmpc_ros.core.plants import NOMINAL, PlantFamily
    from dlmpc_ros.learning.curve import FILE_NAME, load_curve
    from dlmpc_ros.learning.tables import load_baselines
    from dlmpc_ros.training.envelope import cached_plant_envelope, draw_plant
    from dlmpc_ros.training.response import COLUMNS, ResponseConfig, plant_rows
    seed, k_values, offsets = job
    tables = load_baselines(ROOT / 'models/oracle.npz')
    if seed:   # as dlmpc-evaluate draws it, divided by its own envelope
        plant, _ = draw_plant(PlantFamily(), seed, tables)
        envelope = cached_plant_envelope(plant, tables)
    else:      # the nominal cavity, divided by the nominal tables' envelope
        plant, envelope = NOMINAL, tables
    grid, angles, _ = load_curve(ROOT / 'models' / FILE_NAME)
    cfg = ResponseConfig(k_values=k_values, offsets=offsets)
    rows = dict(zip(COLUMNS, plant_rows(plant, seed, cfg, grid, angles).T))
    objective = np.where(rows['E'] > 0, rows['E'] / rows['M'], 0.0)
    out = {'plant': 'nominal' if not seed else f'family-{seed}', 'k': [], 'O_star': [],
           'curve': [], 'best': [], 'best_theta': []}
    for k in k_values:
        at_k = rows['K'] == k
        zero = at_k & (rows['theta'] == 0)
        star = float(np.interp(k, envelope['K'], envelope['O_star']))
        best = int(np.argmax(np.where(at_k, objective, -1)))
        out['k'].append(k)
        out['O_star'].append(star)
        out['curve'].append(float(objective[zero].max()))
        out['best'].append(float(objective[best]))
        out['best_theta'].append(float(rows['theta'][best]))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--k', type=float, nargs='+',
                   default=[-0.28, -0.24, -0.20, -0.16, -0.12, -0.08, -0.04])
    p.add_argument('--offsets', type=float, nargs='+', default=[-0.04, 0.0, 0.04])
    p.add_argument('--workers', type=int, default=default_workers())
    p.add_argument('--out', type=Path, default=ROOT / 'bench/results/rotation_headroom.json')
    args = p.parse_args(argv)
    started = time.monotonic()
    seeds = (0, *DEVELOPMENT, *HELD_OUT)
    results = run_tasks(plant_headroom, [(s, tuple(args.k), tuple(args.offsets))
                                         for s in seeds], args.workers,
                        desc='rotation scans')
    lines = ['| plant | group | curve / O* | best rotation / O* | headroom | best theta [rad] '
             '(min to max over K) |', '|---|---|---|---|---|---|']
    groups: dict[str, list[float]] = {}
    for seed, r in zip(seeds, results):
        star = np.array(r['O_star'])
        curve, best = np.array(r['curve']) / star, np.array(r['best']) / star
        group = ('nominal' if not seed else 'development' if seed in DEVELOPMENT
                 else 'held-out')
        r.update(group=group, headroom=float(np.mean(best - curve)))
        groups.setdefault(group, []).append(r['headroom'])
        lines.append(f"| {r['plant']} | {group} | {curve.mean():.3f} | {best.mean():.3f} | "
                     f"{r['headroom']:+.3f} | {min(r['best_theta']):+.3f} to "
                     f"{max(r['best_theta']):+.3f} |")
    lines += ['', '| group | plants | mean headroom |', '|---|---|---|']
    lines += [f'| {g} | {len(v)} | {np.mean(v):+.4f} |' for g, v in groups.items()]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'k': args.k, 'offsets': args.offsets, 'plants': results,
                                    'wall_seconds': round(time.monotonic() - started)},
                                   indent=1))
    args.out.with_suffix('.md').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
