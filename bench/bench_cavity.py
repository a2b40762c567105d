"""Benchmark the cavity's integration schemes against DOP853 on the same round trips.

Measures, in one run on this machine, for the default solver (the symmetric split step,
32 steps) and each scheme at the fewest steps that keep the issue's accuracy (issue 34):
- one laser (n = 256): median wall time per round trip of ``Cavity.step`` (what the
  laser_sim node calls) and of ``Cavity.run(100)``, the settings interleaved in rounds so
  that a load on the machine falls on all of them alike;
- a batch of lasers: laser round trips per second with the thread-parallel kernel (and on
  one thread, and the floor the FFTs alone set);
- scipy DOP853 on the spec rows at rtol 1e-3 (the issue's baseline, still 1e-8 exact) and
  1e-10 (the reference), timed in the same rounds as the single laser;
- accuracy against DOP853 (rtol 1e-10): E and M after each of 3 round trips of the spec's
  rows and of random angle sets with K in [-0.3, 0.3], and O at the steady state of the
  locked spec rows after 2,000 round trips (the DOP853 side, 1 to 5 minutes a row, is
  kept in ``results/bench_cavity_steady_reference.json``; --steady-reference recomputes it);
- how far each scheme's E, M and O are from the default's (what the shipped models saw).

Usage: ``python bench/bench_cavity.py [--out DIR] [--batch 256] [--rounds 15]``
"""

from __future__ import annotations

import os

# DOP853's stage sums go through BLAS; on 2 shared cores a multi-threaded OpenBLAS makes
# it up to 30x slower (measured), so the baseline gets one thread, like the kernels' single
# laser (set before numpy loads).
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit  # noqa: E402
from rocket_fft import lowlevel  # noqa: E402

from dlmpc_ros.core.cavity import Cavity  # noqa: E402
from dlmpc_ros.core.config import CavityConfig  # noqa: E402
from dlmpc_ros.core.reference import reference_round_trips  # noqa: E402
from dlmpc_ros.core.schemes import ORDER, symmetric_steps  # noqa: E402

ROWS = [((-0.39, -0.25, 0.52, -0.14), 0.10), ((0.30, -1.10, 0.70, 0.25), -0.20),
        ((1.24, -0.24, 0.28, -1.49), 0.00)]
#: The spec rows that lock to one pulse (the second converges to a CW-like state).
LOCKED = (0, 2)
STEADY_ROUND_TRIPS = 2000
#: The symmetric step as the models' data was made before 2026-12-05, the fewest
#: symmetric steps that meet the issue's accuracy, and each fourth-order scheme at its
#: fewest steps (richardson4/6 the default since).
SETTINGS = {
    'strang/32': CavityConfig(scheme='strang', steps_per_round_trip=32),
    'strang/36': CavityConfig(scheme='strang', steps_per_round_trip=36),
    'suzuki4/4': CavityConfig(scheme='suzuki4', steps_per_round_trip=4),
    'richardson4/6': CavityConfig(scheme='richardson4', steps_per_round_trip=6),
    'yoshida4/14': CavityConfig(scheme='yoshida4', steps_per_round_trip=14),
}
#: What the others are compared with (the data the shipped models came from until 2026-12-05).
DEFAULT = 'strang/32'
STEADY_FILE = 'bench_cavity_steady_reference.json'
#: The recorded DOP853 steady states, read unless --steady-reference recomputes them.
STEADY_RECORDED = Path(__file__).resolve().parent / 'results' / STEADY_FILE


def _median(values) -> float:
    return float(np.median(values))


def angle_sets(count: int, seed: int = 34) -> tuple[np.ndarray, np.ndarray]:
    """The spec rows, then ``count`` random angle sets (uniform over a period) and K."""
    rng = np.random.default_rng(seed)
    angles = np.concatenate([np.array([r[0] for r in ROWS]),
                             rng.uniform(-np.pi / 2, np.pi / 2, (count, 4))])
    ks = np.concatenate([[r[1] for r in ROWS], rng.uniform(-0.3, 0.3, count)])
    return angles, ks


def single_laser(rounds: int, steps_per_round: int = 40) -> dict[str, dict[str, float]]:
    """Per setting: median ms per round trip of ``step()`` and of ``run(100)``, and the
    median over rounds of DOP853's time per round trip over ``step()``'s. Each round times
    every setting and DOP853 (3 round trips of one spec row, rtol 1e-3 and 1e-10, the rows
    in turn), so that the machine's load falls on all of them alike."""
    cavities = {name: Cavity(cfg, angles=np.array(ROWS[0][0]), birefringence=ROWS[0][1])
                for name, cfg in SETTINGS.items()}
    for cavity in cavities.values():
        cavity.run(5)  # compile / load the kernel cache
    reference_round_trips(np.array(ROWS[0][0]), ROWS[0][1], 1, rtol=1e-3)
    steps = {name: [] for name in SETTINGS}
    runs = {name: [] for name in SETTINGS}
    ratios = {name: [] for name in SETTINGS}
    dop = {1e-3: [], 1e-10: []}
    for r in range(rounds):
        angles, k = ROWS[r % len(ROWS)]
        for rtol, times in dop.items():
            t0 = time.perf_counter()
            reference_round_trips(np.array(angles), k, 3, rtol=rtol)
            times.append((time.perf_counter() - t0) / 3)
        for name, cavity in cavities.items():
            this_round = []
            for _ in range(steps_per_round):
                t0 = time.perf_counter()
                cavity.step()
                this_round.append(time.perf_counter() - t0)
            steps[name] += this_round
            ratios[name].append(dop[1e-3][-1] / _median(this_round))
            t0 = time.perf_counter()
            cavity.run(100)
            runs[name].append((time.perf_counter() - t0) / 100)
    out = {name: {'step_ms_median': 1e3 * _median(steps[name]),
                  'run100_ms_per_round_trip_median': 1e3 * _median(runs[name]),
                  'dop853_rtol_1e-3_over_step_median_of_rounds': _median(ratios[name])}
           for name in SETTINGS}
    out['dop853'] = {f'rtol_{rtol:g}': {'ms_per_round_trip_median': 1e3 * _median(times)}
                     for rtol, times in dop.items()}
    return out


def batched(batch: int, round_trips: int, repeats: int) -> dict[str, dict[str, float]]:
    """Per setting: laser round trips per second of a batch (all threads, and one)."""
    rng = np.random.default_rng(0)
    angles, ks = rng.uniform(-1.5, 1.5, (batch, 4)), rng.uniform(-0.3, 0.3, batch)
    cavities = {name: Cavity(cfg, batch=batch, angles=angles, birefringence=ks)
                for name, cfg in SETTINGS.items()}
    for cavity in cavities.values():
        cavity.run(2)
    threads = numba.get_num_threads()
    rates = {name: {threads: [], 1: []} for name in SETTINGS}
    for _ in range(repeats):
        for count in (threads, 1):
            numba.set_num_threads(count)
            for name, cavity in cavities.items():
                t0 = time.perf_counter()
                cavity.run(round_trips)
                rates[name][count].append(batch * round_trips / (time.perf_counter() - t0))
    numba.set_num_threads(threads)
    return {name: {'batch': batch, 'threads': threads,
                   'laser_round_trips_per_s_median': _median(rates[name][threads]),
                   'one_thread_laser_round_trips_per_s_median': _median(rates[name][1])}
            for name in SETTINGS}


@njit(cache=True)
def _ffts(x, repeats):
    axes = np.zeros(1, np.int64)
    y = np.empty_like(x)
    for _ in range(repeats):
        lowlevel.c2c(x, y, axes, True, 1.0, 1)
        lowlevel.c2c(y, x, axes, False, 1.0 / x.shape[0], 1)


def fft_microseconds(points: int = 256, repeats: int = 20000) -> float:
    """Median time of one in-place complex FFT of ``points`` points [us]."""
    x = np.exp(1j * np.arange(points, dtype=float))
    _ffts(x, 1)
    times = []
    for _ in range(7):
        t0 = time.perf_counter()
        _ffts(x, repeats)
        times.append((time.perf_counter() - t0) / (2 * repeats))
    return 1e6 * _median(times)


def accuracy(random_sets: int) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """Max relative error of E and M over 3 round trips against DOP853 (rtol 1e-10 and
    1e-3), on the spec rows and on random angle sets; also each setting's (3, S, 3)
    E, M, O for the comparison with the default."""
    angles, ks = angle_sets(random_sets)
    ref = np.array([[[r['E'], r['M']] for r in reference_round_trips(a, k, 3)]
                    for a, k in zip(angles, ks)])  # (S, 3, 2)
    loose = np.array([[[r['E'], r['M']] for r in reference_round_trips(a, k, 3, rtol=1e-3)]
                      for a, k in zip(angles[:3], ks[:3])])
    out = {'dop853_rtol_1e-3': {
        'spec_rows_max_relative_error_E_M': float(np.abs(loose / ref[:3] - 1).max())}}
    values = {}
    for name, cfg in SETTINGS.items():
        result = Cavity(cfg, batch=len(ks), angles=angles, birefringence=ks).run(3)
        got = np.stack([result.E.T, result.M.T], axis=-1)
        error = np.abs(got / ref - 1).max(axis=(1, 2))
        out[name] = {'spec_rows_max_relative_error_E_M': float(error[:3].max()),
                     'random_sets_max_relative_error_E_M': float(error[3:].max()),
                     'random_sets_p99_relative_error_E_M': float(np.quantile(error[3:], 0.99)),
                     'random_sets_median_relative_error_E_M': _median(error[3:]),
                     'random_sets_over_1e-3': int((error[3:] > 1e-3).sum())}
        values[name] = np.stack([result.E, result.M, result.O])
    out['random_sets'] = random_sets
    return out, values


def steady_reference(path: Path, recompute: bool) -> dict[str, float]:
    """DOP853 (rtol 1e-10) O after STEADY_ROUND_TRIPS of each locked spec row."""
    if path.is_file() and not recompute:
        stored = json.loads(path.read_text())
        if stored.get('round_trips') == STEADY_ROUND_TRIPS:
            return stored
    started = time.monotonic()
    rows = {}
    for i in LOCKED:
        angles, k = ROWS[i]
        last = reference_round_trips(np.array(angles), k, STEADY_ROUND_TRIPS)[-1]
        rows[str(i)] = {'angles': list(angles), 'K': k, **last}
    stored = {'integrator': 'scipy DOP853, rtol 1e-10, atol 1e-12',
              'round_trips': STEADY_ROUND_TRIPS, 'rows': rows,
              'wall_seconds': round(time.monotonic() - started, 1)}
    path.write_text(json.dumps(stored, indent=2))
    return stored


def steady_state(reference: dict) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """Relative error of O after STEADY_ROUND_TRIPS of the locked rows, per setting."""
    angles = np.array([ROWS[i][0] for i in LOCKED])
    ks = np.array([ROWS[i][1] for i in LOCKED])
    ref = np.array([reference['rows'][str(i)]['O'] for i in LOCKED])
    out, values = {}, {}
    for name, cfg in SETTINGS.items():
        result = Cavity(cfg, batch=len(ks), angles=angles, birefringence=ks).run(
            STEADY_ROUND_TRIPS).last()
        out[name] = {'max_relative_error_O': float(np.abs(result.O / ref - 1).max()),
                     'converged': bool(result.converged.all())}
        values[name] = result.O
    return out, values


def against_default(values: dict[str, np.ndarray],
                    steady: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Max relative difference from the default's E, M, O (3 round trips; spec rows and
    random sets) and steady-state O: what training data made with the setting would
    change."""
    base, base_steady = values[DEFAULT], steady[DEFAULT]
    out = {}
    for name in SETTINGS:
        if name == DEFAULT:
            continue
        diff = np.abs(values[name] / base - 1)  # (3 quantities, 3 round trips, S)
        out[name] = {
            **{f'spec_rows_max_relative_difference_{q}': float(diff[i, :, :3].max())
               for i, q in enumerate('EMO')},
            **{f'random_sets_max_relative_difference_{q}': float(diff[i, :, 3:].max())
               for i, q in enumerate('EMO')},
            'steady_state_max_relative_difference_O':
                float(np.abs(steady[name] / base_steady - 1).max())}
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--out', type=Path, default=Path('out/bench'))
    p.add_argument('--batch', type=int, default=256)
    p.add_argument('--rounds', type=int, default=15, help='interleaved timing rounds')
    p.add_argument('--random-sets', type=int, default=200)
    p.add_argument('--steady-reference', action='store_true',
                   help=f'recompute {STEADY_FILE} into --out (DOP853, 1 to 5 minutes a '
                        'row); else the one in bench/results is read')
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    print('[1/5] one laser and DOP853 ...', flush=True)
    single = single_laser(args.rounds)
    baseline = single.pop('dop853')
    print('[2/5] batch ...', flush=True)
    batch = batched(args.batch, 20, max(3, args.rounds // 3))
    fft_us = fft_microseconds()
    print('[3/5] accuracy (3 round trips) ...', flush=True)
    acc, values = accuracy(args.random_sets)
    print('[4/5] steady state ...', flush=True)
    steady_ref = steady_reference(args.out / STEADY_FILE if args.steady_reference
                                  else STEADY_RECORDED, args.steady_reference)
    steady, steady_values = steady_state(steady_ref)
    print('[5/5] difference from the default ...', flush=True)
    difference = against_default(values, steady_values)
    loose_ms = baseline['rtol_0.001']['ms_per_round_trip_median']
    tight_ms = baseline['rtol_1e-10']['ms_per_round_trip_median']
    settings = {}
    for name, cfg in SETTINGS.items():
        sym = symmetric_steps(cfg.scheme, cfg.steps)
        floor = 4 * sym * fft_us * 1e-6  # s per laser round trip on one core: its FFTs
        settings[name] = {
            'scheme': cfg.scheme, 'order': ORDER[cfg.scheme],
            'steps_per_round_trip': cfg.steps, 'symmetric_steps': sym,
            'single_laser': single[name], 'batched': batch[name],
            'fft_floor_laser_round_trips_per_s': batch[name]['threads'] / floor,
            'accuracy_3_round_trips': acc[name], 'steady_state': steady[name],
            'speedup_vs_dop853_rtol_1e-3': {
                'single_step': loose_ms / single[name]['step_ms_median'],
                'single_step_median_of_rounds':
                    single[name]['dop853_rtol_1e-3_over_step_median_of_rounds'],
                'single_run100': loose_ms / single[name]['run100_ms_per_round_trip_median']},
            'speedup_vs_dop853_rtol_1e-10_single_step':
                tight_ms / single[name]['step_ms_median'],
            'difference_from_default': difference.get(name),
        }
    report = {
        'machine': {'cpus': os.cpu_count(), 'python': platform.python_version(),
                    'processor': platform.processor() or platform.machine(),
                    'load_average_1_5_15_before': load_before,
                    'load_average_1_5_15_after': os.getloadavg()},
        'dop853': {**baseline, 'accuracy_rtol_1e-3': acc['dop853_rtol_1e-3']},
        'fft_256_points_us': fft_us, 'random_sets': args.random_sets,
        'steady_state_reference': {k: v for k, v in steady_ref.items() if k != 'rows'},
        'settings': settings,
    }
    (args.out / 'bench_cavity.json').write_text(json.dumps(report, indent=2))
    print(f'DOP853: {loose_ms:.1f} ms per round trip at rtol 1e-3, {tight_ms:.1f} at 1e-10 '
          f'(load average before {load_before[0]:.1f}, after {os.getloadavg()[0]:.1f})')
    print(f"{'setting':22s} {'step ms':>8s} {'x DOP853':>9s} {'batch rt/s':>11s} "
          f"{'3-rt err':>9s} {'steady err':>10s}")
    for name, row in settings.items():
        a = row['accuracy_3_round_trips']
        err = max(a['spec_rows_max_relative_error_E_M'], a['random_sets_max_relative_error_E_M'])
        print(f"{name:22s} {row['single_laser']['step_ms_median']:8.3f} "
              f"{row['speedup_vs_dop853_rtol_1e-3']['single_step']:9.0f} "
              f"{row['batched']['laser_round_trips_per_s_median']:11.0f} {err:9.1e} "
              f"{row['steady_state']['max_relative_error_O']:10.1e}")
    print('targets: >= 100x DOP853 (rtol 1e-3), >= 20000 laser round trips/s, errors <= 1e-3')
    print(f'report: {args.out / "bench_cavity.json"}')


if __name__ == '__main__':
    main()
