"""Where the bringup's start-up time goes: launch to a connected graph, node by node.

Runs ``bringup --controller CONTROLLER --round-trips 50`` ``--repeats`` times and reads,
for each run, the wall time from launching the bringup to its first line (its own
imports), to each node's ``ready`` log line (imports, models, node construction; the
nodes start together, so on 2 cores they share the CPU) and to ``graph connected``
(the first state and K at the monitor: every node ready, every match discovered). What
is left after the last node is ready is discovery and matching. ``--first-run`` deletes
the package's byte code and numba's kernel cache before every run, as a fresh install
without ``make venv``'s precompile step would have them.

    .venv/bin/python bench/startup.py --repeats 7 --out bench/results/startup.json
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
READY = re.compile(r'\[INFO\] \[(\d+\.\d+)\] \[(\w+)\]: ready ')


def clear_caches() -> None:
    """Remove the package's byte code and numba cache (what ``make venv`` precompiles)."""
    for cache in (ROOT / 'dlmpc_ros').rglob('__pycache__'):
        shutil.rmtree(cache)


def one_run(controller: str, domain: int) -> dict[str, float]:
    """Seconds from launch to the bringup's first line, to each node's ``ready``, to
    ``graph connected``, and the whole run."""
    with tempfile.TemporaryDirectory() as logs:
        launch = time.time()
        output = []
        proc = subprocess.Popen(
            [str(ROOT / '.venv/bin/bringup'), '--controller', controller, '--round-trips',
             '50', '--domain-id', str(domain), '--log-dir', logs],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        times: dict[str, float] = {}
        for line in proc.stdout:
            now = time.time() - launch
            output.append(line)
            times.setdefault('bringup_first_line', now)
            if 'graph connected' in line:
                times['connected'] = now
        proc.wait()
        times['exit'] = time.time() - launch
        if proc.returncode != 0 or 'connected' not in times:
            raise RuntimeError(f'bringup failed (exit code {proc.returncode}):\n'
                               + ''.join(output[-20:]))
        for log in Path(logs).glob('*.log'):
            for match in READY.finditer(log.read_text()):
                times[f'ready_{match[2]}'] = float(match[1]) - launch
    ready = [v for k, v in times.items() if k.startswith('ready_')]
    times['after_last_ready'] = times['connected'] - max(ready)
    return times


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--controller', default='dlmpc')
    p.add_argument('--repeats', type=int, default=5)
    p.add_argument('--first-run', action='store_true',
                   help='clear byte code and numba cache before every run')
    p.add_argument('--domain-id', type=int, default=191)
    p.add_argument('--out', type=Path)
    args = p.parse_args()
    runs = []
    for i in range(args.repeats):
        if args.first_run:
            clear_caches()
        runs.append(one_run(args.controller, args.domain_id))
        print(f'run {i + 1}/{args.repeats}: connected after {runs[-1]["connected"]:.2f} s',
              flush=True)
    keys = sorted({k for run in runs for k in run}, key=lambda k: statistics.median(
        run.get(k, 0.0) for run in runs))
    median = {k: statistics.median(run[k] for run in runs if k in run) for k in keys}
    print(f'{"seconds from launch (median of " + str(len(runs)) + ")":<40s}{"median":>8s}'
          f'{"min":>8s}{"max":>8s}')
    for k in keys:
        values = [run[k] for run in runs if k in run]
        print(f'{k:<40s}{median[k]:8.2f}{min(values):8.2f}{max(values):8.2f}')
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({'controller': args.controller,
                                        'first_run': args.first_run, 'runs': runs,
                                        'median': median}, indent=1))
    if args.first_run:  # leave the caches as make venv does
        subprocess.run([str(ROOT / '.venv/bin/python'), '-c', 'from dlmpc_ros.core.cavity '
                        'import compile_kernels; compile_kernels()'], check=True)
        subprocess.run([str(ROOT / '.venv/bin/python'), '-m', 'compileall', '-q',
                        str(ROOT / 'dlmpc_ros')], check=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
