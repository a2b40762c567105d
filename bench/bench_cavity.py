"""Benchmark the cavity simulator against a DOP853 integration of the same round trips.

Measures, in one run on this machine:
- one laser (n = 256, default solver): median wall time per round trip of ``Cavity.step``
  (what the laser_sim node calls) and of ``Cavity.run(100)``;
- a batch of lasers: laser round trips per second with the thread-parallel kernel;
- scipy DOP853 (rtol 1e-10, the authors' integrator) on the same round trips;
- the split-step accuracy against DOP853 on the spec's reference rows.

Usage: ``python bench/bench_cavity.py [--out DIR] [--batch 256] [--repeats 500]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.reference import reference_round_trips

ROWS = [((-0.39, -0.25, 0.52, -0.14), 0.10), ((0.30, -1.10, 0.70, 0.25), -0.20),
        ((1.24, -0.24, 0.28, -1.49), 0.00)]


def single_laser(repeats: int) -> dict[str, float]:
    cavity = Cavity(angles=np.array(ROWS[0][0]), birefringence=ROWS[0][1])
    cavity.run(5)  # compile / load the kernel cache
    step_times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cavity.step()
        step_times.append(time.perf_counter() - t0)
    run_times = []
    for _ in range(max(5, repeats // 50)):
        t0 = time.perf_counter()
        cavity.run(100)
        run_times.append((time.perf_counter() - t0) / 100)
    return {'step_ms_median': 1e3 * float(np.median(step_times)),
            'step_ms_p90': 1e3 * float(np.percentile(step_times, 90)),
            'run100_ms_per_round_trip_median': 1e3 * float(np.median(run_times))}


def batched(batch: int, round_trips: int, repeats: int = 5) -> dict[str, float]:
    rng = np.random.default_rng(0)
    cavity = Cavity(batch=batch, angles=rng.uniform(-1.5, 1.5, (batch, 4)),
                    birefringence=rng.uniform(-0.3, 0.3, batch))
    cavity.run(2)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        cavity.run(round_trips)
        rates.append(batch * round_trips / (time.perf_counter() - t0))
    return {'batch': batch, 'laser_round_trips_per_s_median': float(np.median(rates))}


def dop853(round_trips: int) -> dict[str, float]:
    times = []
    for angles, k in ROWS:
        t0 = time.perf_counter()
        reference_round_trips(np.array(angles), k, round_trips)
        times.append((time.perf_counter() - t0) / round_trips)
    return {'ms_per_round_trip_median': 1e3 * float(np.median(times)),
            'ms_per_round_trip_each_row': [1e3 * t for t in times]}


def accuracy() -> dict[str, float]:
    worst = 0.0
    for angles, k in ROWS:
        ref = reference_round_trips(np.array(angles), k, 3)
        got = Cavity(CavityConfig(), angles=np.array(angles), birefringence=k).run(3)
        for i, r in enumerate(ref):
            worst = max(worst, abs(got.E[i, 0] / r['E'] - 1), abs(got.M[i, 0] / r['M'] - 1))
    return {'max_relative_error_E_M_first_3_round_trips': worst}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--out', type=Path, default=Path('out/bench'))
    p.add_argument('--batch', type=int, default=256)
    p.add_argument('--repeats', type=int, default=500)
    args = p.parse_args()
    print('[1/4] one laser ...', flush=True)
    single = single_laser(args.repeats)
    print('[2/4] batch ...', flush=True)
    batch = batched(args.batch, 20)
    print('[3/4] DOP853 baseline ...', flush=True)
    baseline = dop853(3)
    print('[4/4] accuracy ...', flush=True)
    acc = accuracy()
    ref_ms = baseline['ms_per_round_trip_median']
    report = {
        'machine': {'cpus': os.cpu_count(), 'python': platform.python_version(),
                    'processor': platform.processor() or platform.machine()},
        'settings': CavityConfig().to_dict(),
        'single_laser': single, 'batched': batch, 'dop853': baseline, 'accuracy': acc,
        'speedup_vs_dop853': {
            'single_step': ref_ms / single['step_ms_median'],
            'batched_per_laser_round_trip':
                ref_ms * batch['laser_round_trips_per_s_median'] / 1e3,
        },
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'bench_cavity.json').write_text(json.dumps(report, indent=2))
    print(f"one laser, n=256:   {single['step_ms_median']:.3f} ms per round trip (median of "
          f"{args.repeats} steps; target <= 0.5)  = "
          f"{report['speedup_vs_dop853']['single_step']:.0f}x faster than DOP853")
    print(f"batch of {args.batch}:      {batch['laser_round_trips_per_s_median']:.0f} laser round "
          f"trips/s (target >= 5000) = "
          f"{report['speedup_vs_dop853']['batched_per_laser_round_trip']:.0f}x DOP853")
    print(f"DOP853 (rtol 1e-10): {ref_ms:.1f} ms per round trip (median of 3 rows)")
    print(f"accuracy vs DOP853:  max relative error of E, M over 3 round trips x 3 rows = "
          f"{acc['max_relative_error_E_M_first_3_round_trips']:.2e} (target <= 1e-3)")
    print(f'report: {args.out / "bench_cavity.json"}')


if __name__ == '__main__':
    main()
