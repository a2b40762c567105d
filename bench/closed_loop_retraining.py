"""Does training the planner's predictor on the controller's own closed-loop data help?

Issue 15's first remedy for a planner that finds angles where its predictor is wrong:
run the controller, aggregate what it measured, retrain, repeat. Each round:

1. runs the DL-MPC on training plants of the family (seeds 2001 and up, the plants the
   predictor's rotation data came from; never the development plants 1-8 or the held-out
   101-108), on a random walk of K with drift seed 77 (no evaluation seed), fast mode:
   round 1 exploring (``PlannerConfig.explore``: every plan a random turn of the curve
   within the trust radius, taken back if O falls, as ``bringup --controller explore``
   records a calibration bag) with the shipped models, every later round planning with
   the predictor of the round before, so the data holds the states its own plans reach;
2. makes every run's settled states into training pairs as ``dlmpc-train adapt`` makes
   them from a bag (:func:`dlmpc_ros.training.adapt.laser_pairs`: no K, no plant
   parameter), and adds them to the pairs of the rounds before;
3. fine-tunes the shipped ensemble on the aggregated pairs of all but the last
   ``--val-plants`` plants, with the L2 pull toward its shipped weights, each member kept
   at the epoch that predicts the other plants' pairs best
   (:func:`dlmpc_ros.training.adapt.fine_tune`);
4. writes the models folder ``OUT/round-N/models`` (the shipped files, the retrained
   ``response.pt``) for ``bench/dlmpc_variants.py`` (variant ``{"models_dir": ...}``).

::

    python bench/closed_loop_retraining.py --plants 40 --rounds 3 --out /tmp/retrain

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

from dlmpc_ros.scaleout import default_workers, run_tasks

ROOT = Path(__file__).resolve().parents[1]
DRIFT_SEED = 77


def closed_loop_run(job: tuple[int, int, str]) -> dict[str, np.ndarray]:
    """The control periods (``round_trip``, ``E``, ``M``, ``angles``) of one DL-MPC run on
    family plant ``job[0]`` of ``job[1]`` round trips with the models of ``job[2]``
    (exploring with the shipped models: ``''``)."""
    from dlmpc_ros.control.dlmpc_config import DLMPCConfig
    from dlmpc_ros.control.factory import load_dlmpc
    from dlmpc_ros.control.limits import AngleLimits
    from dlmpc_ros.control.rotation_planner import PlannerConfig
    from dlmpc_ros.evaluation.runs import RunSpec, run_fast
    from dlmpc_ros.training.envelope import PlantTask, draw_task
    plant_seed, round_trips, models_dir = job
    models = Path(models_dir) if models_dir else ROOT / 'models'
    plant = draw_task(PlantTask(str(ROOT / 'models/oracle.npz'), seed=plant_seed))['plant']
    spec = RunSpec('random_walk', DRIFT_SEED, 'dlmpc', round_trips=round_trips, plant=plant)
    controller = load_dlmpc(models, DLMPCConfig(limits=AngleLimits(max_step=spec.max_step),
                                                planner=PlannerConfig(explore=not models_dir)))
    record = run_fast(spec, models, controller)
    i = np.searchsorted(record.round_trip, record.control_round_trip)
    keep = np.isfinite(record.E[i]) & np.isfinite(record.M[i]) & (record.E[i] > 0)
    i = i[keep]
    return {'round_trip': record.round_trip[i], 'E': record.E[i], 'M': record.M[i],
            'angles': record.angles[i]}


def closed_loop_runs(seeds: list[int], round_trips: int, models_dir: str, workers: int,
                     cache: Path) -> list[dict[str, np.ndarray]]:
    """The runs on ``seeds`` with ``models_dir``, read from ``cache`` where made before."""
    cache.mkdir(parents=True, exist_ok=True)
    path = {s: cache / f'{s}-{round_trips}.npz' for s in seeds}
    todo = [s for s in seeds if not path[s].is_file()]
    made = run_tasks(closed_loop_run, [(s, round_trips, models_dir) for s in todo], workers,
                     desc='closed-loop runs')
    for s, run in zip(todo, made):
        np.savez(path[s], **run)
    return [dict(np.load(path[s])) for s in seeds]


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
    p.add_argument('--rounds', type=int, default=1)
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)
    if not 0 < args.val_plants < args.plants:
        p.error('--val-plants must be between 0 and --plants')
    started = time.monotonic()
    models = ROOT / 'models'
    seeds = list(range(2001, 2001 + args.plants))
    grid, curve, _ = load_curve(models / FILE_NAME)
    cfg = AdaptConfig(epochs=args.epochs)
    cut = args.plants - args.val_plants
    fit_pairs: list[tuple[np.ndarray, np.ndarray]] = []
    val_pairs: list[tuple[np.ndarray, np.ndarray]] = []
    rounds, previous = [], ''
    for r in range(1, args.rounds + 1):
        runs = closed_loop_runs(seeds, args.round_trips, previous, args.workers,
                                args.out / 'runs' / f'round-{r}')
        pairs = [laser_pairs(run, grid, curve, cfg)[:2] for run in runs]
        fit_pairs += pairs[:cut]
        val_pairs += pairs[cut:]
        x, y = (np.concatenate([q[k] for q in fit_pairs]) for k in (0, 1))
        x_val, y_val = (np.concatenate([q[k] for q in val_pairs]) for k in (0, 1))
        model, payload = load_response(models / 'response.pt')
        before = {'fit': _rmse(model, x, y), 'held_out_plants': _rmse(model, x_val, y_val)}
        epochs = fine_tune(model, x, y, x_val, y_val, cfg)
        after = {'fit': _rmse(model, x, y), 'held_out_plants': _rmse(model, x_val, y_val)}
        out_models = args.out / f'round-{r}' / 'models'
        shutil.copytree(models, out_models, dirs_exist_ok=True)
        report = {'round': r, 'collected_with': previous or 'shipped models, exploring',
                  'new_pairs': int(sum(q[1].size for q in pairs)), 'pairs': int(y.size),
                  'held_out_pairs': int(y_val.size), 'rmse_before': before,
                  'rmse_after': after, 'epochs_kept': epochs}
        save_checkpoint(out_models / 'response.pt', 'response', model.state_dict(),
                        payload['config'], {**payload.get('metrics', {}),
                                            'closed_loop_retraining': report},
                        payload.get('data_fingerprint', ''))
        rounds.append(report)
        print(json.dumps(report), flush=True)
        previous = str(out_models)
    (args.out / 'retraining.json').write_text(json.dumps(
        {'plants': seeds, 'validation_plants': seeds[cut:], 'drift_seed': DRIFT_SEED,
         'round_trips': args.round_trips, 'rounds': rounds,
         'wall_seconds': round(time.monotonic() - started)}, indent=1))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
