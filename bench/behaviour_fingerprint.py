"""The DL-MPC's behaviour in a few hashes, to check that a refactoring changed nothing.

Eight short fast runs (8,000 round trips each) that between them exercise every part of
the controller: the nominal cavity and two family plants (the issue-32 plant: pump 1.60,
saturation energy 4.6, loss 0.115, dispersion -0.35; one near development family 5, where
K's crossings of 0 ask for turns within the wait after one: ``turn_crossing.md``, and its
random walk falls after a kept turn: ``kept_turn_no_wait.md``; and the
nominal cavity's steps, where turns wind the servos to an end: ``wound_servos.md``),
stress-suite conditions with ideal and slow servos and 1 % detector noise (scan, entries,
branch turns, planned turns, held angles), and ``strategy:=paper`` (the inner loop and the
MP-RNN's outer loop). Per
run it prints the mean O, the periods per mode and a hash of every round trip's angles;
with ``--check FILE`` it compares them with a recorded run and exits 1 on any difference.
The hashes are of float64 arrays: compare on one machine and library set
(``requirements.txt``).

Usage::

    python bench/behaviour_fingerprint.py --out before.json    # before the change
    python bench/behaviour_fingerprint.py --check before.json  # after it
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
#: A family-range plant (issue 32's first example).
PLANT = {'pump': 1.60, 'saturation_energy': 4.6, 'loss': 0.115, 'dispersion': -0.35}
#: A plant near development family 5 (rounded).
PLANT_5 = {'pump': 1.857, 'saturation_energy': 4.75, 'loss': 0.106, 'dispersion': -0.443,
           'gain_bandwidth': 0.0822}
#: (label, controller, plant, stress condition, seed).
CASES = (('nominal', 'dlmpc', {}, 'sin6k-ideal', 1),
         ('issue-plant', 'dlmpc', PLANT, 'walk-servo6', 2),
         ('issue-plant', 'dlmpc', PLANT, 'steps-noise1', 1),
         ('nominal', 'dlmpc', {}, 'steps-servo3', 3),
         ('family-5-like', 'dlmpc', PLANT_5, 'sin6k-ideal', 1),
         ('family-5-like', 'dlmpc', PLANT_5, 'walk-ideal', 1),
         ('nominal', 'dlmpc', {}, 'steps-noise1', 2),
         ('nominal', 'dlmpc_paper', {}, 'sin6k-ideal', 1))
ROUND_TRIPS = 8000


def fingerprint(models: Path) -> list[dict]:
    """One row per case: what it ran, mean O, periods per mode, angles' hash."""
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.evaluation.suites import stress_conditions
    conditions = stress_conditions()
    rows = []
    for label, controller, plant, name, seed in CASES:
        c = conditions[name]
        started = time.perf_counter()
        record = run_fast(RunSpec(scenario=c.scenario, seed=seed, controller=controller,
                                  settings=c.settings, bench=c.bench, plant=plant,
                                  round_trips=ROUND_TRIPS, condition=name), models)
        modes, counts = np.unique(record.mode_names, return_counts=True)
        rows.append({'case': f'{label} {controller} {name} seed {seed}',
                     'mean_O': float(np.nanmean(record.O)),
                     'modes': {str(m): int(n) for m, n in zip(modes, counts)},
                     'angles_sha256': hashlib.sha256(
                         np.ascontiguousarray(record.angles).tobytes()).hexdigest()[:16]})
        print(f"{rows[-1]['case']}: mean O {rows[-1]['mean_O']:.15g}, {rows[-1]['modes']}, "
              f"angles {rows[-1]['angles_sha256']} ({time.perf_counter() - started:.0f} s)",
              flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--out', type=Path, help='write the rows as JSON here')
    p.add_argument('--check', type=Path, help='a recorded --out file to compare with')
    args = p.parse_args(argv)
    recorded = None
    if args.check:
        try:
            recorded = json.loads(args.check.read_text())
        except (OSError, ValueError) as err:
            p.error(f'cannot read {args.check}: {err}')
    rows = fingerprint(args.models_dir)
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1) + '\n')
    if recorded is None:
        return 0
    changed = [r['case'] for r, old in zip(rows, recorded) if r != old]
    if changed or len(rows) != len(recorded):
        print(f'behaviour changed: {changed or "a different set of cases"}')
        return 1
    print(f'same behaviour as {args.check} in all {len(rows)} runs')
    return 0


if __name__ == '__main__':
    sys.exit(main())
