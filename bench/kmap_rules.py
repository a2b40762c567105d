"""Subset rules of the K-to-angles map, side by side: each rule's map trained by
``dlmpc-train kmap``'s own functions and measured one-shot (steady O at the map's angles
over O*(K) from the oracle's state and from the median sweep state), and optionally in
closed loop (``--seeds``: DL-MPC with that map, fast mode, the evaluation presets).

The shipped rule was chosen in closed loop (``docs/results/kmap-rules.md``); the one-shot
figures alone did not rank the rules right.

Usage::

    python bench/kmap_rules.py --data-dir data --models-dir models \\
        --out bench/results/kmap_rules.json [--seeds 1 2 3]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: (intervals, delta, top, jump_penalty) of the rules compared at stop 9 (kmap-rules.md).
RULES = ((21, 1.0, 20, 0.1), (21, 1.0, 50, 10.0), (31, 1.0, 50, 10.0))
SCENARIOS = ('sinusoidal', 'chirp', 'random_walk', 'steps')


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--data-dir', type=Path, default=ROOT / 'data')
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--seeds', type=int, nargs='*', default=[],
                   help='closed-loop runs of DL-MPC with each map (none: one-shot only)')
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)

    from dlmpc_ros.core.config import CavityConfig
    from dlmpc_ros.evaluation.metrics import run_metrics
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.learning.checkpoint import save_checkpoint
    from dlmpc_ros.learning.kmap import KMapConfig
    from dlmpc_ros.learning.tables import load_baselines, load_envelope
    from dlmpc_ros.learning.vae import load_vae
    from dlmpc_ros.training import shards
    from dlmpc_ros.training.stages.kmap import (SubsetRule, evaluate_map, map_training_pairs,
                                                median_states, train_kmap)
    from dlmpc_ros.training.workspace import Workspace

    ws = Workspace(args.data_dir, args.models_dir)
    vae, _ = load_vae(ws.model('vae'))
    sweep = shards.load_dataset(ws.sweep)
    envelope = load_envelope(ws.oracle)
    median = median_states(sweep, envelope['K'])
    results = []
    for intervals, delta, top, penalty in RULES:
        rule = SubsetRule(intervals=intervals, delta=delta, top=top, jump_penalty=penalty)
        centres, targets, target_o = map_training_pairs(vae, sweep, rule)
        kmap, _ = train_kmap(centres, targets, KMapConfig())
        row = {'rule': rule.to_dict(),
               'from_oracle_state': float(np.mean(evaluate_map(
                   vae, kmap, envelope, CavityConfig(), envelope['angles'])['ratio'])),
               'from_median_state': float(np.mean(evaluate_map(
                   vae, kmap, envelope, CavityConfig(), median)['ratio']))}
        if args.seeds:
            with tempfile.TemporaryDirectory() as scratch:
                models = Path(shutil.copytree(args.models_dir, Path(scratch) / 'models'))
                save_checkpoint(models / 'kmap.pt', 'kmap', kmap.state_dict(),
                                kmap.config.to_dict(), {'subset_mean_O': float(target_o.mean())},
                                'bench')
                tables = load_baselines(models / 'oracle.npz')
                row['closed_loop'] = {
                    f'{scenario}/{seed}': run_metrics(run_fast(
                        RunSpec(scenario, seed, 'dlmpc', round_trips=args.round_trips),
                        models), tables)['oracle_ratio']
                    for scenario in SCENARIOS for seed in args.seeds}
        results.append(row)
        print(json.dumps(row), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
