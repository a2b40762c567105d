"""Throughput of ``ModeLockedLaser-v0``: the single environment beside the vector
environment over the batched cavity (and, for reference, Gymnasium's SyncVectorEnv of B
single environments), in env steps (control periods) per second and laser round trips
per second.

Every setting runs ``--steps`` env steps of random actions after a warm-up (the kernels
compiled and the lasers past their first period), in ``--rounds`` rounds with the
settings interleaved, so that a load on the machine falls on all of them alike; the
result is each setting's median over the rounds. The vector env is measured with numba's
thread-parallel kernel on every core and on one thread (``numba.set_num_threads``).

Usage: ``python bench/bench_gym.py [--out bench/results] [--batch 16 64] [--points 256]
[--solver-steps 32] [--steps 20] [--rounds 5] [--name bench_gym]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import gymnasium
import numba
import numpy as np

import dlmpc_ros.gym  # noqa: F401  (registers the id)

ENV = 'dlmpc_ros.gym:ModeLockedLaser-v0'


def steps_per_second(env, steps: int, batch: int, seed: int) -> float:
    """Env steps per second of ``steps`` calls of random actions (B env steps a call)."""
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    started = time.perf_counter()
    for action in actions:
        env.step(action)
    return steps * batch / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path(__file__).parent / 'results')
    parser.add_argument('--batch', type=int, nargs='+', default=[16, 64])
    parser.add_argument('--points', type=int, default=256, help='grid points of the cavity')
    parser.add_argument('--solver-steps', type=int, default=32,
                        help='split steps per round trip (steps_per_round_trip)')
    parser.add_argument('--name', default='bench_gym', help='name of the result files')
    parser.add_argument('--steps', type=int, default=20, help='env steps (calls) per round')
    parser.add_argument('--rounds', type=int, default=5)
    parser.add_argument('--period', type=int, default=10)
    args = parser.parse_args()
    options = {'solver': {'points': args.points, 'steps_per_round_trip': args.solver_steps},
               'period': args.period,
               'scenario': 'sinusoidal', 'episode_periods': 10 ** 6}
    cores = numba.config.NUMBA_NUM_THREADS
    settings: dict[str, tuple] = {'single env': (gymnasium.make(ENV, **options), 1, cores)}
    for b in args.batch:
        vector = gymnasium.make_vec(ENV, num_envs=b, **options)
        settings[f'vector env B={b} ({cores} threads)'] = (vector, b, cores)
        settings[f'vector env B={b} (1 thread)'] = (vector, b, 1)
        settings[f'SyncVectorEnv of {b} single envs'] = (
            gymnasium.make_vec(ENV, num_envs=b, vectorization_mode='sync', **options), b, 1)
    for seed, (env, _, _) in enumerate(settings.values()):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        env.step(env.action_space.sample())          # compiled and warm
    rates: dict[str, list[float]] = {name: [] for name in settings}
    for round_ in range(args.rounds):
        for name, (env, batch, threads) in settings.items():
            numba.set_num_threads(threads)
            rates[name].append(steps_per_second(env, args.steps, batch, round_))
        numba.set_num_threads(cores)
        print(f'round {round_ + 1}/{args.rounds}: ' + ', '.join(
            f'{name} {rate[-1]:.0f}' for name, rate in rates.items()), flush=True)
    single = float(np.median(rates['single env']))
    table = {name: {'batch': settings[name][1], 'threads': settings[name][2],
                    'env_steps_per_s': float(np.median(r)),
                    'round_trips_per_s': float(np.median(r)) * args.period,
                    'vs_single_env': float(np.median(r)) / single,
                    'per_round': [float(x) for x in r]} for name, r in rates.items()}
    result = {'options': options, 'steps_per_round': args.steps, 'rounds': args.rounds,
              'statistic': 'median over rounds',
              'machine': {'cpus': os.cpu_count(), 'numba_threads': cores,
                          'python': platform.python_version(), 'numpy': np.__version__,
                          'gymnasium': gymnasium.__version__,
                          'load_average_at_end': list(os.getloadavg()),
                          'note': 'shared with other experiments while measured'},
              'settings': table}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f'{args.name}.json').write_text(json.dumps(result, indent=2))
    lines = ['| setting | env steps/s | laser round trips/s | vs single env |',
             '|---|---|---|---|']
    lines += [f"| {name} | {row['env_steps_per_s']:.0f} | {row['round_trips_per_s']:.0f} | "
              f"{row['vs_single_env']:.2f}x |" for name, row in table.items()]
    batches = ' '.join(map(str, args.batch))
    command = (f'python bench/bench_gym.py --batch {batches} --points {args.points} '
               f'--solver-steps {args.solver_steps} --steps {args.steps} '
               f'--rounds {args.rounds} --name {args.name}')
    (args.out / f'{args.name}.md').write_text(
        f"# ModeLockedLaser-v0 throughput\n\n`{command}`: n = {args.points} points, "
        f"{args.solver_steps} split steps per round trip, P = "
        f"{args.period} round trips per step, sinusoidal drift, random actions; medians "
        f"of {args.rounds} interleaved rounds on {os.cpu_count()} cores shared with other "
        f"experiments (load average {os.getloadavg()[0]:.1f} at the end).\n\n"
        + '\n'.join(lines) + '\n')
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
