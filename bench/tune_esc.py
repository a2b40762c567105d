"""Tune and measure the extremum-seeking controller on the drift scenarios.

Two modes:

- ``tune``: candidate settings (``--candidates FILE.json``: a list of ``{name: {field:
  value}}`` overrides of :class:`ESCConfig`) run side by side as one batch of lasers
  (one per candidate, scenario and seed) through a batched copy of the closed loop
  (same order as :func:`run_closed_loop`: K per round trip, a blown-up laser reset, one
  measurement per control period); prints and writes each candidate's metrics.
- ``report``: the default settings through :func:`run_closed_loop` itself, one run per
  scenario and seed, written to ``bench/results/esc_tuning.json`` (with ``--tried``,
  the tuning log is copied in).

Usage: ``python bench/tune_esc.py report [--seeds 0 1 2] [--round-trips 20000]``
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from dlmpc_ros.control.esc import ESCConfig, ESCController
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.evaluation.closed_loop import random_initial_angles, run_closed_loop
from dlmpc_ros.evaluation.metrics import run_metrics
from dlmpc_ros.evaluation.presets import CHECK_CASES, preset_scenario
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.learning.tables import load_envelope

ROOT = Path(__file__).resolve().parents[1]
#: The tuning objective's scenarios: the check set of the presets (label -> preset, seed).
SCENARIOS = CHECK_CASES
#: Extra scenarios for quick looks (not part of the tuning objective).
EXTRA = {'constant': ('constant', 1)}
PERIOD = 10
KEYS = ('oracle_ratio', 'locked_fraction', 'acquisition_round_trips', 'mean_O')


def batched_runs(configs: list[ESCConfig], scenarios: list, starts: np.ndarray,
                 round_trips: int) -> list[RunRecord]:
    """One laser per (config, scenario, start) triple given as equal-length lists."""
    batch = len(configs)
    controllers = [ESCController(config=c) for c in configs]
    cavity = Cavity(batch=batch, angles=starts, birefringence=0.0)
    o = np.full((round_trips, batch), np.nan)
    e, m = o.copy(), o.copy()
    k = np.empty((round_trips, batch))
    for r in range(1, round_trips + 1):
        k[r - 1] = [s(r) for s in scenarios]
        cavity.set_birefringence(k[r - 1])
        applied = cavity.angles
        result = cavity.step()
        blown = ~result.finite
        if blown.any():
            cavity.reset(np.flatnonzero(blown))
        o[r - 1], e[r - 1], m[r - 1] = result.O, result.E, result.M
        if r % PERIOD:
            continue
        new = applied.copy()
        for b in np.flatnonzero(~blown):
            step = controllers[b].step(np.array([e[r - 1, b], m[r - 1, b], *applied[b]]))
            new[b] = step.angles
        cavity.set_angles(new)
    rt = np.arange(1, round_trips + 1)
    return [RunRecord(round_trip=rt, K=k[:, b], E=e[:, b], M=m[:, b], O=o[:, b],
                      angles=np.zeros((round_trips, 4))) for b in range(batch)]


def summarize(metrics: list[dict]) -> dict:
    ratio = [mt['oracle_ratio'] for mt in metrics]
    return {'mean_oracle_ratio': float(np.mean(ratio)),
            'min_oracle_ratio': float(np.min(ratio)),
            'mean_locked_fraction': float(np.mean([mt['locked_fraction'] for mt in metrics])),
            'never_locked': int(sum(mt['acquisition_round_trips'] is None for mt in metrics))}


def tune(args: argparse.Namespace) -> None:
    envelope = load_envelope(ROOT / 'data' / 'oracle.npz')
    candidates = json.loads(Path(args.candidates).read_text())
    table = {**SCENARIOS, **EXTRA}
    names = [n for n in table if n in args.scenarios]
    configs, scenarios, starts, tags = [], [], [], []
    for cand in candidates:
        (label, overrides), = cand.items()
        overrides = {key: tuple(v) if isinstance(v, list) else v
                     for key, v in overrides.items()}
        cfg = replace(ESCConfig(), **overrides)
        for name in names:
            preset, scenario_seed = table[name]
            for seed in args.seeds:
                configs.append(cfg)
                scenarios.append(preset_scenario(preset, scenario_seed))
                starts.append(random_initial_angles(seed))
                tags.append((label, name, seed))
    started = time.perf_counter()
    records = batched_runs(configs, scenarios, np.array(starts), args.round_trips)
    wall = time.perf_counter() - started
    results: dict[str, dict] = {}
    for tag, record in zip(tags, records):
        label, name, seed = tag
        mt = run_metrics(record, envelope)
        entry = results.setdefault(label, {'runs': {}})
        entry['runs'][f'{name}/seed{seed}'] = {key: mt[key] for key in KEYS}
    for label, entry in results.items():
        entry.update(summarize(list(entry['runs'].values())))
        print(f"{label:>24}: ratio {entry['mean_oracle_ratio']:.3f} "
              f"(min {entry['min_oracle_ratio']:.3f}) locked {entry['mean_locked_fraction']:.2f} "
              f"never {entry['never_locked']}  | "
              + ' '.join(f"{r['oracle_ratio']:.2f}" for r in entry['runs'].values()))
    print(f'{len(records)} lasers x {args.round_trips} round trips in {wall:.0f} s')
    if args.out:
        log = Path(args.out)
        previous = json.loads(log.read_text()) if log.exists() else []
        previous.append({'candidates': candidates, 'seeds': args.seeds,
                         'round_trips': args.round_trips, 'wall_s': wall, 'results': results})
        log.write_text(json.dumps(previous, indent=1))


def report(args: argparse.Namespace) -> None:
    envelope = load_envelope(ROOT / 'data' / 'oracle.npz')
    cfg = ESCConfig()
    runs = {}
    started = time.perf_counter()
    for name, (preset, scenario_seed) in SCENARIOS.items():
        for seed in args.seeds:
            record = run_closed_loop(ESCController(config=cfg),
                                     preset_scenario(preset, scenario_seed),
                                     args.round_trips,
                                     initial_angles=random_initial_angles(seed))
            mt = run_metrics(record, envelope)
            runs[f'{name}/seed{seed}'] = {key: mt[key] for key in
                                          (*KEYS, 'step_latency_ms_median')}
            print(name, seed, {key: mt[key] for key in KEYS}, flush=True)
    out = {'settings': asdict(cfg), 'round_trips': args.round_trips, 'period': PERIOD,
           'seeds': args.seeds, 'scenarios': {n: {'preset': preset, 'seed': seed}
                                              for n, (preset, seed) in SCENARIOS.items()},
           'summary': summarize(list(runs.values())), 'runs': runs,
           'wall_s': time.perf_counter() - started}
    if args.tried and Path(args.tried).exists():
        out['tried'] = json.loads(Path(args.tried).read_text())
    path = ROOT / 'bench' / 'results' / 'esc_tuning.json'
    path.write_text(json.dumps(out, indent=1))
    print(json.dumps(out['summary']), '->', path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('mode', choices=('tune', 'report'))
    parser.add_argument('--candidates', default='', help='tune: JSON list of overrides')
    parser.add_argument('--scenarios', nargs='+', default=list(SCENARIOS))
    parser.add_argument('--seeds', nargs='+', type=int, default=[0])
    parser.add_argument('--round-trips', type=int, default=20000)
    parser.add_argument('--out', default='', help='tune: JSON log to append to')
    parser.add_argument('--tried', default='', help='report: tuning log to include')
    args = parser.parse_args()
    tune(args) if args.mode == 'tune' else report(args)


if __name__ == '__main__':
    main()
