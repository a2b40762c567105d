"""Closed-loop ablation of DL-MPC settings: each variant on every scenario and seed.

A variant is a set of :class:`DLMPCConfig` overrides; every run goes through
``dlmpc-evaluate --fast``'s own run (:func:`dlmpc_ros.evaluation.runs.run_fast`: same
scenario presets, initial angles, servo limit and models), so a variant with no overrides
reproduces the DL-MPC column of ``make evaluate``.

Usage::

    python bench/dlmpc_variants.py --variants variants.json --seeds 1 2 3 \\
        --out bench/results/outer_loop.json --jobs 2

``variants.json`` maps names to overrides, e.g. ``{"shipped": {}, "monitored":
{"monitor_prediction": true}, "no tracking": {"tracking": null}, "slow tracking":
{"tracking": {"max_step": 0.015}}, "noisy": {"measurement_noise": 0.01}}`` (``tracking``
takes the fields of :class:`~dlmpc_ros.control.tracking.TrackingConfig`;
``measurement_noise`` is the run's relative noise on the measured E and M). Writes the
runs' metrics (plus the fraction of periods in each mode) as JSON and a markdown table of
mean O / O* (mean over seeds, min-max) beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ('sinusoidal', 'chirp', 'random_walk', 'steps')


def run_one(job: tuple[str, dict, str, int, int, str]) -> dict:
    """One closed-loop run: (variant, overrides, scenario, seed, round trips, models)."""
    from dlmpc_ros.control.dlmpc_config import DLMPCConfig
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.control.limits import AngleLimits
    from dlmpc_ros.control.step import MODES
    from dlmpc_ros.control.tracking import TrackingConfig
    from dlmpc_ros.evaluation.metrics import run_metrics
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.learning.tables import load_baselines

    name, overrides, scenario, seed, round_trips, models = job
    overrides = dict(overrides)
    noise = float(overrides.pop('measurement_noise', 0.0))  # a run setting, not DLMPCConfig
    if isinstance(overrides.get('tracking'), dict):  # from JSON: the tracker's fields
        overrides['tracking'] = TrackingConfig(**overrides['tracking'])
    spec = RunSpec(scenario, seed, 'dlmpc', round_trips=round_trips, measurement_noise=noise)
    controller = load_dlmpc(Path(models), DLMPCConfig(limits=AngleLimits(max_step=spec.max_step),
                                                      **overrides))
    started = time.monotonic()
    record = run_fast(spec, Path(models), controller)
    metrics = run_metrics(record, load_baselines(Path(models) / 'oracle.npz'))
    modes = np.asarray(record.mode)
    return {'variant': name, 'scenario': scenario, 'seed': seed,
            'wall_seconds': round(time.monotonic() - started, 1),
            'mode_fractions': {m: float(np.mean(modes == i)) for i, m in enumerate(MODES)
                               if np.any(modes == i)},
            **{k: metrics[k] for k in ('oracle_ratio', 'locked_fraction',
                                       'acquisition_round_trips', 'mean_O')}}


def table(runs: list[dict]) -> str:
    """Markdown: variant x scenario, mean O / O* over seeds (min-max), and the share of
    periods in the outer loop and in curve tracking."""
    lines = ['| variant | ' + ' | '.join(SCENARIOS) + ' | outer loop share | track share |',
             '|---' * (len(SCENARIOS) + 3) + '|']
    for variant in dict.fromkeys(r['variant'] for r in runs):
        cells, share = [], {'outer': [], 'track': []}
        for scenario in SCENARIOS:
            mine = [r for r in runs if r['variant'] == variant and r['scenario'] == scenario]
            ratios = [r['oracle_ratio'] for r in mine]
            for mode, values in share.items():
                values += [r['mode_fractions'].get(mode, 0.0) for r in mine]
            cells.append(f'{np.mean(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f})'
                         if ratios else '')
        lines.append(f'| {variant} | ' + ' | '.join(cells) + ' | ' + ' | '.join(
            f'{min(v):.2f}-{max(v):.2f}' for v in share.values()) + ' |')
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--variants', type=Path, required=True)
    p.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--out', type=Path, default=ROOT / 'bench/results/dlmpc_variants.json')
    p.add_argument('--jobs', type=int, default=2)
    args = p.parse_args(argv)
    variants = json.loads(args.variants.read_text())
    jobs = [(name, overrides, scenario, seed, args.round_trips, str(args.models_dir))
            for name, overrides in variants.items() for seed in args.seeds
            for scenario in SCENARIOS]
    runs = []
    with ProcessPoolExecutor(args.jobs) as pool:
        for i, run in enumerate(pool.map(run_one, jobs), 1):
            runs.append(run)
            print(f"[{i}/{len(jobs)}] {run['variant']} {run['scenario']} seed {run['seed']}: "
                  f"O/O* {run['oracle_ratio']:.3f}, locked {run['locked_fraction']:.2f}, "
                  f"acquired {run['acquisition_round_trips']}, outer "
                  f"{run['mode_fractions'].get('outer', 0.0):.2f} ({run['wall_seconds']} s)",
                  flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({'variants': variants, 'seeds': args.seeds,
                                    'round_trips': args.round_trips, 'runs': runs}, indent=1))
    args.out.with_suffix('.md').write_text(table(runs))
    print(table(runs))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
