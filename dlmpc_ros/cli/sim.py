"""dlmpc-sim: explore the cavity without ROS, one JSON object per round trip.

Example: ``dlmpc-sim --angles -0.39 -0.25 0.52 -0.14 --birefringence 0.1 --round-trips 200``
prints ``{"round_trip": 1, "E": ..., "M": ..., "O": ..., "energy": ..., "peak": ...,
"pulses": ...}`` lines and a final ``{"converged": ..., "round_trips": ..., "finite": ...}``.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import fields

import numpy as np

from dlmpc_ros.core.cavity import INITIAL_CONDITIONS, Cavity
from dlmpc_ros.core.config import CavityConfig

KEYS = ('round_trip', 'E', 'M', 'O', 'energy', 'peak', 'pulses')
CHUNK = 64


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog='dlmpc-sim', description=__doc__.split('\n\n')[0])
    p.add_argument('--angles', type=float, nargs=4, default=[-0.39, -0.25, 0.52, -0.14],
                   metavar=('A1', 'A2', 'A3', 'AP'),
                   help='alpha1 alpha2 alpha3 alpha_p in radians (default: %(default)s)')
    p.add_argument('--birefringence', '-K', type=float, default=0.1,
                   help='birefringence K (default: %(default)s)')
    p.add_argument('--round-trips', type=int, default=100,
                   help='round trips (default: %(default)s)')
    p.add_argument('--every', type=int, default=1, help='print every M-th round trip')
    p.add_argument('--initial', choices=INITIAL_CONDITIONS, default='sech')
    p.add_argument('--seed', type=int, default=0, help='seed of the noise initial condition')
    p.add_argument('--until-steady', action='store_true',
                   help='stop at the first round trip that meets the steady-state rule '
                        '(without it, every requested round trip runs)')
    for f in fields(CavityConfig):  # the fields' own defaults: steps 0 is the scheme's own
        p.add_argument('--' + f.name.replace('_', '-'), type=type(f.default),
                       default=f.default, help='(default: %(default)s)')
    args = p.parse_args(argv)
    if args.round_trips < 1 or args.every < 1:
        p.error('--round-trips and --every must be >= 1')
    try:
        args.config = CavityConfig(**{f.name: getattr(args, f.name) for f in fields(CavityConfig)})
    except ValueError as err:
        p.error(str(err))
    if not np.isfinite(args.angles).all() or not np.isfinite(args.birefringence):
        p.error('--angles and --birefringence must be finite')
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    cavity = Cavity(args.config, angles=np.array(args.angles), birefringence=args.birefringence,
                    initial=args.initial, seed=args.seed)
    converged = False
    finite = True
    stop = False
    while cavity.round_trip < args.round_trips and not stop:
        result = cavity.run(min(CHUNK, args.round_trips - cavity.round_trip))
        for i in range(result.E.shape[0]):
            row = {key: getattr(result, key)[i, 0].item() for key in KEYS}
            finite = bool(result.finite[i, 0])
            converged = bool(result.converged[i, 0])
            if not finite:
                print(json.dumps({'round_trip': row['round_trip'],
                                  'error': 'field is no longer finite'}))
                stop = True
                break
            if row['round_trip'] % args.every == 0 or (converged and args.until_steady):
                print(json.dumps(row))
            if converged and args.until_steady:
                stop = True
                break
        done = int(row['round_trip'])
    print(json.dumps({'converged': converged, 'round_trips': done, 'finite': finite}))
    return 0 if finite else 1


if __name__ == '__main__':
    sys.exit(main())
