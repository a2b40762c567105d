"""Which branch holds more at a K once turned: the settled O along the curve and its twin.

For one plant (``--plant-family`` seed, 0: the nominal cavity) at one K (``--k``, read as
a diagnosis: no controller sees it), every curve point ``s`` of a 13-point grid over
[-0.3, 0.3] on both branches (the curve ``c(s)``, the twin ``c(-s) + pi/2``) is turned by
every ``theta`` of a 17-point grid over [-0.8, 0.8] rad (all four angles) and run 1,500
round trips from the cavity's default state. Printed per branch, as fractions of the
plant's envelope O*(K): the best O unturned, and the best over the turns with its theta
and s (``bench/results/turn_rotation.md``). With ``--profile``, instead the settled O
unturned at each point the acquisition scan visits (``CURVE_POINTS``, past the curve's end
on the tracker's lines), on the curve ``c(u)`` and on its twin ``c(u) + pi/2``
(``bench/results/scan_from_reach.md``)::

    python bench/branch_headroom.py --plant-family 2 --k -0.3 [--profile]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
POINTS = np.linspace(-0.3, 0.3, 13)
TURNS = np.linspace(-0.8, 0.8, 17)
ROUND_TRIPS = 1500


def settled_ratio(plant, envelope: dict, k: float, batch: np.ndarray) -> np.ndarray:
    """Each angle set (n, 4) [rad] of ``batch`` run ``ROUND_TRIPS`` round trips from the
    cavity's default state at K = ``k``: its settled O over the envelope's O*(K), (n,)."""
    from dlmpc_ros.core.cavity import Cavity
    cavity = Cavity(plant, batch=len(batch), angles=batch, birefringence=np.full(len(batch), k))
    cavity.run(ROUND_TRIPS)
    last = cavity.run(1).last()
    star = float(np.interp(k, envelope['K'], envelope['O_star']))
    return np.where(last.E > 0, last.E / last.M, 0.0) / star


def main(argv: list[str] | None = None) -> int:
    from dlmpc_ros.core.plants import NOMINAL, PlantFamily
    from dlmpc_ros.core.symmetry import QUARTER_TURN
    from dlmpc_ros.learning.curve import FILE_NAME, load_curve
    from dlmpc_ros.learning.tables import load_baselines
    from dlmpc_ros.training.envelope import cached_plant_envelope, draw_plant
    from dlmpc_ros.training.response import curve_angles
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--plant-family', type=int, default=0, help='family seed; 0: nominal')
    p.add_argument('--k', type=float, required=True)
    p.add_argument('--profile', action='store_true', help='O at the scan points, unturned')
    args = p.parse_args(argv)
    tables = load_baselines(ROOT / 'models/oracle.npz')
    if args.plant_family:
        plant, _ = draw_plant(PlantFamily(), args.plant_family, tables)
        envelope = cached_plant_envelope(plant, tables)
    else:
        plant, envelope = NOMINAL, tables
    grid, angles, _ = load_curve(ROOT / 'models' / FILE_NAME)
    if args.profile:
        return profile(plant, envelope, args.k, grid, angles)
    branches = (curve_angles(grid, angles, POINTS),  # (13, 4) each
                curve_angles(grid, angles, -POINTS) + QUARTER_TURN)
    batch = np.concatenate([b + t for b in branches for t in TURNS])
    ratio = settled_ratio(plant, envelope, args.k, batch).reshape(2, TURNS.size, POINTS.size)
    star = float(np.interp(args.k, envelope['K'], envelope['O_star']))
    print(f'plant {args.plant_family or "nominal"}, K {args.k:+.2f}, envelope O* {star:.4f}')
    for name, o in zip(('curve', 'twin'), ratio):
        i, j = np.unravel_index(int(np.argmax(o)), o.shape)
        print(f'{name}: unturned {o[TURNS.size // 2].max():.3f}; best {o[i, j]:.3f} at '
              f'theta {TURNS[i]:+.2f} rad, s {POINTS[j]:+.2f}')
    return 0


def profile(plant, envelope: dict, k: float, grid: np.ndarray, angles: np.ndarray) -> int:
    """Print the settled O / O*(K) at the scan's points on the curve and its twin."""
    from dlmpc_ros.control.dlmpc import CURVE_POINTS
    from dlmpc_ros.control.tracking import CurveTracker
    from dlmpc_ros.core.symmetry import QUARTER_TURN
    tracker = CurveTracker(grid, angles, threshold=1.0)
    points = np.array([tracker.on_curve(u) for u in CURVE_POINTS])  # (9, 4)
    batch = np.concatenate([points, points + QUARTER_TURN])
    ratio = settled_ratio(plant, envelope, k, batch).reshape(2, len(CURVE_POINTS))
    star = float(np.interp(k, envelope['K'], envelope['O_star']))
    print(f'K {k:+.2f}, O* {star:.4f}; u ' + ' '.join(f'{u:+.2f}' for u in CURVE_POINTS))
    for name, o in zip(('curve', 'twin '), ratio):
        print(f'{name}' + ' ' * 21 + ' '.join(f'{x:5.2f}' for x in o))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
