"""Does training the planner's predictor on the controller's own closed-loop data help?

Issue 15's first remedy for a planner that finds angles where its predictor is wrong:
run the controller, aggregate what it measured, retrain, repeat. One round here:

1. the DL-MPC runs exploring (``PlannerConfig.explore``: every plan a random turn of the
   curve within the trust radius, taken back if O falls, as ``bringup --controller
   explore`` records a calibration bag) on training plants of the family (seeds 2001 and
   up, the plants the predictor's rotation data came from; never the development plants
   1-8 or the held-out 101-108), on a random walk of K with drift seed 77 (no evaluation
   seed), fast mode;
2. every run's settled states become training pairs as ``dlmpc-train adapt`` makes them
   from a bag (:func:`dlmpc_ros.training.adapt.laser_pairs`: no K, no plant parameter);
3. the shipped ensemble is fine-tuned on the pairs of all but the last ``--val-plants``
   plants, with the L2 pull toward its shipped weights, each member kept at the epoch
   that predicts the other plants' pairs best (:func:`dlmpc_ros.training.adapt.fine_tune`);
4. the models folder ``OUT/models`` (the shipped files, the retrained ``response.pt``) is
   written for ``bench/dlmpc_variants.py`` (variant ``{"models_dir": "OUT/models"}``).

::

    python bench/closed_loop_retraining.py --plants 40 --out /tmp/retrain

Writes ``OUT/retraining.json`` (pairs, errors before and after, epochs kept).
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from dlmpc_ros.scaleout import default_workers, run_tasks

ROOT = Path(__file__).resolve().parents[1]
DRIFT_SEED = 77


def exploring_run(job: tuple[int, int]) -> dict[str, np.ndarray]:
    """The control periods (``round_trip``, ``E``, ``M``, ``angles``) of one exploring
    DL-MPC run on family plant ``job[0]`` of ``job[1]`` round trips."""
    from dlmpc_ros.control.dlmpc_config import DLMPCConfig
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.control.limits import AngleLimits
    from dlmpc_ros.control.rotation_planner import PlannerConfig
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.training.envelope import PlantTask, draw_task
    plant_seed, round_trips = job
    models = ROOT / 'models'
    plant = draw_task(PlantTask(str(models / 'oracle.npz'), seed=plant_seed))['plant']
    spec = RunSpec('random_walk', DRIFT_SEED, 'dlmpc', round_trips=round_trips, plant=plant)
    controller = load_dlmpc(models, DLMPCConfig(limits=AngleLimits(max_step=spec.max_step),
                                                planner=PlannerConfig(explore=True)))
    record = run_fast(spec, models, controller)
    i = np.searchsorted(record.round_trip, record.control_round_trip)
    keep = np.isfinite(record.E[i]) & np.isfinite(record.M[i]) & (record.E[i] > 0)
    i = i[keep]
    return {'round_trip': record.round_trip[i], 'E': record.E[i], 'M': record.M[i],
            'angles': record.angles[i]}


def main(argv: list[str] | None = None) -> int:
    from dlmpc_ros.learning.checkpoint import save_checkpoint
    from dlmpc_ros.learning.curve import FILE_NAME, load_curve
    from dlmpc_ros.learning.response import load_response
    from dlmpc_ros.training.adapt import AdaptConfig, _rmse, fine_tune, laser_pairs

    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--plants', type=int, default=40, help='family plants 2001, 2002, ...')
    p.add_argument('--val-plants', type=int, default=8,
                   help='the last this many plants choose the epochs')
    p.add_argument('--round-trips', type=int, default=20000)
    p.add_argument('--epochs', type=int, default=40)
    p.add_argument('--workers', type=int, default=default_workers())
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)
    if not 0 < args.val_plants < args.plants:
        p.error('--val-plants must be between 0 and --plants')
    started = time.monotonic()
    models = ROOT / 'models'
    seeds = list(range(2001, 2001 + args.plants))
    runs = run_tasks(exploring_run, [(s, args.round_trips) for s in seeds], args.workers,
                     desc='exploring runs')
    grid, curve, _ = load_curve(models / FILE_NAME)
    cfg = AdaptConfig(epochs=args.epochs)
    pairs = [laser_pairs(run, grid, curve, cfg)[:2] for run in runs]
    cut = args.plants - args.val_plants
    x, y = (np.concatenate([q[k] for q in pairs[:cut]]) for k in (0, 1))
    x_val, y_val = (np.concatenate([q[k] for q in pairs[cut:]]) for k in (0, 1))
    model, payload = load_response(models / 'response.pt')
    before = {'fit': _rmse(model, x, y), 'held_out_plants': _rmse(model, x_val, y_val)}
    epochs = fine_tune(model, x, y, x_val, y_val, cfg)
    after = {'fit': _rmse(model, x, y), 'held_out_plants': _rmse(model, x_val, y_val)}
    out_models = args.out / 'models'
    shutil.copytree(models, out_models, dirs_exist_ok=True)
    report = {'plants': seeds, 'validation_plants': seeds[cut:], 'drift_seed': DRIFT_SEED,
              'round_trips': args.round_trips, 'pairs': int(y.size),
              'held_out_pairs': int(y_val.size), 'rmse_before': before, 'rmse_after': after,
              'epochs_kept': epochs, 'wall_seconds': round(time.monotonic() - started)}
    save_checkpoint(out_models / 'response.pt', 'response', model.state_dict(),
                    payload['config'], {**payload.get('metrics', {}),
                                        'closed_loop_retraining': report},
                    payload.get('data_fingerprint', ''))
    (args.out / 'retraining.json').write_text(json.dumps(report, indent=1))
    print(json.dumps(report, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
