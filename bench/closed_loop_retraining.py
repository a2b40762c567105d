"""Does training the planner's predictor on the controller's own closed-loop data help?

Issue 15's first remedy for a planner that finds angles where its predictor is wrong:
run the controller, aggregate what it measured, retrain, repeat. Each round:

1. runs the DL-MPC on training plants of the family as ``dlmpc-train response`` does
   (:mod:`dlmpc_ros.training.closed_loop`: plants 2001 and up, a random walk of K of
   drift seed 77, fast mode): round 1 exploring with the shipped models, every later
   round planning with the predictor of the round before, so the data holds the states
   its own plans reach;
2. makes every run's settled states into training pairs as ``dlmpc-train adapt`` makes
   them from a bag (:func:`dlmpc_ros.training.adapt.laser_pairs`: no K, no plant
   parameter), and adds them to the pairs of the rounds before;
3. fine-tunes the shipped ensemble on the aggregated pairs of all but the last
   ``--val-plants`` plants, with the L2 pull toward its shipped weights, each member kept
   at the epoch that predicts the other plants' pairs best
   (:func:`dlmpc_ros.training.adapt.fine_tune`).
   With ``--rotation-data DIR`` (the pretraining's rotation data, ``data/response`` of
   ``make models``) it instead fits a new ensemble as ``dlmpc-train response`` does (seed
   0: on that data alone it gives the shipped weights back) on the rotation data's
   training pairs and every closed-loop pair so far, so that the data keeps the large
   rotations and the cliff the closed-loop runs never reach (DAgger's aggregation with
   the original data; its round 1 is what ``dlmpc-train response`` ships since
   2026-12-04);
4. writes the models folder ``OUT/round-N/models`` (the shipped files, the retrained
   ``response.pt``) for ``bench/dlmpc_variants.py`` (variant ``{"models_dir": ...}``).

::

    python bench/closed_loop_retraining.py --plants 40 --rounds 3 --out /tmp/retrain
    python bench/closed_loop_retraining.py --plants 40 --rounds 3 \\
        --rotation-data data/response --out /tmp/aggregated

Writes ``OUT/retraining.json`` (per round: pairs, errors before and after, epochs kept);
the runs are kept in ``OUT/runs/`` and read back by a later call with the same ``--out``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.scaleout import default_workers

ROOT = Path(__file__).resolve().parents[1]


def rotation_pairs(directory: Path) -> dict[str, np.ndarray]:
    """The pretraining's pairs of the rotation data in ``directory`` (``dlmpc-train
    response``'s ``data/response``): inputs and targets of its training plants (``x``,
    ``y``) and of its held-out plants (``x_held``, ``y_held``), as the shipped stage splits
    them."""
    from dlmpc_ros.training import shards
    from dlmpc_ros.training.stages.response import (FitSettings, PairRule, joined_pairs,
                                                    profile_pairs, split_pairs)
    rule = PairRule()
    x, y, _, held = split_pairs(shards.load_dataset(directory), rule, FitSettings.held_out)
    x_held, y_held = joined_pairs([profile_pairs(p, rule) for p in held])
    return {'x': x, 'y': y, 'x_held': x_held, 'y_held': y_held}


def main(argv: list[str] | None = None) -> int:
    from dlmpc_ros.learning.checkpoint import save_checkpoint
    from dlmpc_ros.learning.curve import FILE_NAME, load_curve
    from dlmpc_ros.learning.response_file import load_response
    from dlmpc_ros.training.adapt import AdaptConfig, fine_tune, laser_pairs, prediction_rmse
    from dlmpc_ros.training.closed_loop import ClosedLoopConfig, closed_loop_runs
    from dlmpc_ros.training.stages.response import FitSettings, fit_ensemble, joined_pairs

    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--plants', type=int, default=40, help='family plants 2001, 2002, ...')
    p.add_argument('--val-plants', type=int, default=8,
                   help='the last this many plants choose the epochs')
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--epochs', type=int, default=40)
    p.add_argument('--workers', type=int, default=default_workers())
    p.add_argument('--rounds', type=int, default=1)
    p.add_argument('--rotation-data', type=Path, default=None,
                   help="aggregate with the pretraining's rotation data in this folder (a "
                        "workspace's data/response): each round fits a new ensemble as "
                        "`dlmpc-train response` does (seed 0) on its pairs and every "
                        "closed-loop pair so far, instead of fine-tuning the shipped one")
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)
    if not 0 < args.val_plants < args.plants:
        p.error('--val-plants must be between 0 and --plants')
    started = time.monotonic()
    models = ROOT / 'models'
    runs_cfg = ClosedLoopConfig(plants=args.plants, validation_plants=args.val_plants,
                                round_trips=args.round_trips)
    seeds = runs_cfg.seeds
    grid, curve, _ = load_curve(models / FILE_NAME)
    cfg = AdaptConfig(epochs=args.epochs)
    cut = args.plants - args.val_plants
    rotation = rotation_pairs(args.rotation_data) if args.rotation_data else None
    fit_pairs: list[tuple[np.ndarray, np.ndarray]] = []
    val_pairs: list[tuple[np.ndarray, np.ndarray]] = []
    rounds, previous = [], ''
    for r in range(1, args.rounds + 1):
        runs = closed_loop_runs(runs_cfg, Path(previous or models),
                                args.out / 'runs' / f'round-{r}', args.workers,
                                explore=not previous)
        pairs = [laser_pairs(run, grid, curve, cfg)[:2] for run in runs]
        fit_pairs += pairs[:cut]
        val_pairs += pairs[cut:]
        x, y = joined_pairs(fit_pairs)
        x_val, y_val = joined_pairs(val_pairs)
        model, payload = load_response(models / 'response.pt')

        judged = {'fit': (x, y), 'held_out_plants': (x_val, y_val)}
        if rotation is not None:
            judged['rotation_data_held_out_plants'] = (rotation['x_held'], rotation['y_held'])
        before = {k: prediction_rmse(model, *pairs) for k, pairs in judged.items()}
        if rotation is None:
            epochs = fine_tune(model, x, y, x_val, y_val, cfg)
        else:
            model, _ = fit_ensemble(np.r_[rotation['x'], x], np.r_[rotation['y'], y],
                                    FitSettings(), seed=0)
            epochs = [FitSettings.epochs] * len(model.members)
        after = {k: prediction_rmse(model, *pairs) for k, pairs in judged.items()}
        out_models = args.out / f'round-{r}' / 'models'
        shutil.copytree(models, out_models, dirs_exist_ok=True)
        report = {'round': r, 'collected_with': previous or 'shipped models, exploring',
                  'aggregated_with_rotation_data': rotation is not None,
                  'rotation_pairs': int(rotation['y'].size) if rotation is not None else 0,
                  'new_pairs': int(sum(q[1].size for q in pairs)), 'pairs': int(y.size),
                  'held_out_pairs': int(y_val.size), 'rmse_before': before,
                  'rmse_after': after, 'epochs_kept': epochs}
        save_checkpoint(out_models / 'response.pt', 'response', model.state_dict(),
                        model.config.to_dict(),
                        {**payload.get('metrics', {}), 'closed_loop_retraining': report},
                        payload.get('data_fingerprint', ''))
        rounds.append(report)
        print(json.dumps(report), flush=True)
        previous = str(out_models)
    (args.out / 'retraining.json').write_text(json.dumps(
        {'plants': seeds, 'validation_plants': seeds[cut:], 'drift_seed': runs_cfg.drift_seed,
         'round_trips': args.round_trips, 'rounds': rounds,
         'wall_seconds': round(time.monotonic() - started)}, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
