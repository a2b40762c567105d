"""Would an angle dither make K identifiable? A supervised probe on simulated dithers.

One measurement ``(E, M, alpha)`` determines K only to |r| about 0.87 (supervised;
``dlmpc-train check-estimator``): at fixed angles E rises and falls with K, so one E fits
two K. This experiment asks how much a small, known dither of each waveplate adds.

``--settings`` angle sets (the oracle's settings for random K', so good operating points)
are each crossed with ``--k-points`` values of K uniform in [-0.3, 0.3], so that the
angles say nothing about K: run to steady state at alpha, then step each of the four
angles by ``--dither`` rad in turn (warm, ``--settle`` round trips) and record (E, M)
there too. A probe (an MLP trained on K, comparison only) reads the plain measurement, or
the measurement plus the four local slopes of (E, log M) that the dithers measure. Writes
``bench/results/dither_identifiability.json``.

Usage: ``python bench/dither_identifiability.py [--settings 4] [--k-points 384]``
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.learning.features import Normalizer, features
from dlmpc_ros.learning.identifiability import ProbeConfig, probe_features_r
from dlmpc_ros.learning.oracle import envelope_angles, load_envelope

ROOT = Path(__file__).resolve().parents[1]


def simulate(settings: int, k_points: int, dither: float, settle: int, seed: int,
             models: Path) -> dict:
    """Steady (E, M) at alpha and at the four one-angle dithers; arrays per laser."""
    rng = np.random.default_rng(seed)
    lasers = settings * k_points
    k = rng.uniform(-0.3, 0.3, lasers)
    setting_angles = envelope_angles(load_envelope(models / 'oracle.npz'),
                                     rng.uniform(-0.3, 0.3, settings))      # (settings, 4)
    alpha = np.repeat(setting_angles, k_points, axis=0)
    copies = 5  # the setting itself and one dither per angle
    cavity = Cavity(batch=lasers * copies, angles=np.repeat(alpha, copies, axis=0),
                    birefringence=np.repeat(k, copies), seed=seed)
    base = run_to_steady(cavity, 400, 10)
    dithered = np.repeat(alpha, copies, axis=0).reshape(lasers, copies, 4)
    for j in range(4):
        dithered[:, j + 1, j] += dither
    cavity.set_angles(dithered.reshape(-1, 4))
    after = run_to_steady(cavity, settle, 10)
    shape = (lasers, copies)
    return {'K': k, 'alpha': alpha, 'E': base.E.reshape(shape)[:, 0],
            'M': base.M.reshape(shape)[:, 0], 'pulses': base.pulses.reshape(shape)[:, 0],
            'finite': base.finite.reshape(shape).all(1) & after.finite.reshape(shape).all(1),
            'E_dithered': after.E.reshape(shape)[:, 1:],
            'M_dithered': after.M.reshape(shape)[:, 1:]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--settings', type=int, default=4)
    p.add_argument('--k-points', type=int, default=384)
    p.add_argument('--dither', type=float, default=0.05)
    p.add_argument('--settle', type=int, default=100)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--out', type=Path, default=ROOT / 'bench/results/dither_identifiability.json')
    args = p.parse_args(argv)
    started = time.monotonic()
    d = simulate(args.settings, args.k_points, args.dither, args.settle, args.seed,
                 args.models_dir)
    ok = d['finite']
    k = d['K'][ok]
    plain = np.column_stack([d['E'], d['M'], d['alpha']])[ok]          # (N, 6)
    norm = Normalizer.fit(plain[:, 0], plain[:, 1])
    # The dithers as local slopes: d(E_n)/d(alpha_j) and d(logM_n)/d(alpha_j), (N, 8).
    states = norm.states(torch.as_tensor(d['E']), torch.as_tensor(d['M']))[ok]       # (N, 2)
    dithered = norm.states(torch.as_tensor(d['E_dithered']),
                           torch.as_tensor(d['M_dithered']))[ok]                    # (N, 4, 2)
    slopes = ((dithered - states[:, None, :]) / args.dither).flatten(1)
    x_plain = features(torch.as_tensor(plain), norm).float()                          # (N, 10)
    x_dither = torch.cat([x_plain, slopes.float()], dim=1)                           # (N, 18)
    train = np.random.default_rng(args.seed).random(k.size) < 0.8
    pulsed = d['pulses'][ok] >= 1
    config = ProbeConfig(hidden=64, epochs=300)
    result = {'settings': vars(args) | {'models_dir': str(args.models_dir),
                                        'out': str(args.out)},
              'lasers_finite': int(ok.sum()), 'pulsed': int(pulsed.sum())}
    for name, mask in (('all', np.ones(k.size, bool)), ('pulsed', pulsed)):
        result[name] = {
            'one measurement': probe_features_r(x_plain[mask], k[mask], train[mask], config),
            'with the four dither slopes': probe_features_r(x_dither[mask], k[mask],
                                                            train[mask], config)}
        print(name, {key: round(v, 3) for key, v in result[name].items()}, flush=True)
    result['wall_seconds'] = round(time.monotonic() - started, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
