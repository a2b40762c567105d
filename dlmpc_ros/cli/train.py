"""dlmpc-train: train, measure and ship the models (estimator, map, predictor).

``dlmpc-train all`` runs ``vae``, ``kmap``, ``mprnn``, ``baselines``, ``curve`` and
``response`` in order on the datasets of ``dlmpc-data`` and writes
``models/{vae,kmap,mprnn}.pt``, the baseline angle tables ``models/oracle.npz`` (+
``.json``), the DL-MPC's tracking curve ``models/track_curve.npz`` (from the baseline
tables; ``curve`` alone remakes it from the shipped ``oracle.npz`` in a second), the
steady-response predictor ``models/response.pt`` (from rotation data of plants drawn from
the family, made into ``data/response`` first when missing: a quarter of an hour on 2
cores), ``models/metrics.json``, ``models/figures/`` and ``models/MODEL_CARD.md``.
``--quick`` trains tiny models for tests.
``adapt --bag DIR --out MODELS`` calibrates the models of ``--models-dir`` to a lab's
laser from a bag of ``bringup --controller explore --record DIR`` (``--round-trips N``:
its first N round trips only) and writes a models folder to run with
(:mod:`dlmpc_ros.training.adapt`): the planner's correction, the rotation to start
from (``--laser-estimator``: also the laser's own estimator and map).
``drl`` trains the deep-RL baseline (Stable-Baselines3 PPO on the Gymnasium environment of
the laser over the plant family, about 20 minutes on one core; not part of ``all``, ``make
models`` runs it after) and writes ``models/drl_policy.npz`` + ``.json`` (plain arrays and
JSON, no pickles) and ``models/figures/drl_reward.png`` (:mod:`dlmpc_ros.training.stages.drl`).
``check-estimator`` measures where the shipped estimator's surrogate gets its information
(angles or E and M; needs true K, so it is an evaluation) and writes a report to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from dlmpc_ros.control.step import MEASUREMENT_ROUND_TRIPS
from dlmpc_ros.learning.model_files import ModelFileError
from dlmpc_ros.scaleout import default_workers
from dlmpc_ros.training.workspace import Workspace

STAGES = ('all', 'vae', 'kmap', 'mprnn', 'baselines', 'curve', 'response', 'check-estimator',
          'adapt', 'drl')


def run_stages(stage: str, ws: Workspace, seed: int, quick: bool, show: bool,
               workers: int = 1, drl: dict | None = None) -> None:
    """Run ``stage`` (or every stage for ``all``), writing each one's metrics; ``drl``:
    the deep-RL stage's settings over :class:`~dlmpc_ros.training.drl.DRLConfig`'s."""
    if stage in ('all', 'vae'):
        from dlmpc_ros.training.stages.vae import train_vae_stage
        metrics = train_vae_stage(ws, seed, epochs=2 if quick else 25, show_progress=show)
        ws.write_metrics('vae', metrics)
        print(f"vae: |r| = {metrics['abs_pearson_r_heldout']:.3f} (window "
              f"{metrics['chosen_window']})", flush=True)
    if stage in ('all', 'kmap'):
        from dlmpc_ros.training.stages.kmap import train_kmap_stage
        metrics = train_kmap_stage(ws, seed, steps=200 if quick else 3000)
        ws.write_metrics('kmap', metrics)
        print(f"kmap: O/O* = {metrics['oracle_ratio_test_k']:.3f} (test K)", flush=True)
    if stage in ('all', 'mprnn'):
        from dlmpc_ros.training.stages.mprnn import train_mprnn_stage
        metrics = train_mprnn_stage(ws, seed, quick=quick, show_progress=show)
        ws.write_metrics('mprnn', metrics)
        print(f"mprnn: horizon-{len(metrics['rmse_O_model'])} O error / persistence = "
              f"{metrics['rmse_O_model'][-1] / metrics['rmse_O_persistence'][-1]:.3f}",
              flush=True)
    if stage in ('all', 'baselines'):
        from dlmpc_ros.training.stages.baselines import train_baselines_stage
        metrics = train_baselines_stage(ws, quick=quick, show_progress=show)
        ws.write_metrics('baselines', metrics)
        first = next(iter(metrics['closed_loop']))
        ratios = {name: round(r['oracle_ratio'], 3)
                  for name, r in metrics['closed_loop'][first].items()}
        print(f'baselines: closed-loop O/O* on {first}: {ratios}', flush=True)
    if stage in ('all', 'baselines', 'curve'):
        from dlmpc_ros.training.stages.curve import train_curve_stage
        metrics = train_curve_stage(ws.models_dir)
        ws.write_metrics('curve', metrics)
        print(f"curve: {metrics['points']} points, mean steady O "
              f"{metrics['mean_objective']:.4f}", flush=True)
    if stage in ('all', 'response'):
        from dlmpc_ros.training.stages.response import train_response_stage
        metrics = train_response_stage(ws, seed, quick=quick, show_progress=show,
                                       workers=workers)
        ws.write_metrics('response', metrics)
        plans = metrics['heldout_plans']
        print(f"response: held-out RMSE of log O {metrics['heldout_rmse_where_kept']:.4f}, "
              f"plans gain {plans['share_of_best_gain']:.2f} of the best turn, "
              f"{plans['plans_that_lose_the_pulse']} of {plans['plans']} lose the pulse",
              flush=True)
    if stage == 'drl':
        train_drl(ws, seed, quick, show, drl or {})


def train_drl(ws: Workspace, seed: int, quick: bool, show: bool, settings: dict) -> None:
    """The deep-RL baseline's stage (its metrics go to ``models/metrics.json``)."""
    from dataclasses import replace

    from dlmpc_ros.training.drl import DRLConfig
    from dlmpc_ros.training.stages.drl import quick_config, train_drl_stage
    config = quick_config(seed) if quick else DRLConfig(seed=seed)
    config = replace(config, **{k: v for k, v in settings.items() if v})
    metrics = train_drl_stage(ws, seed, quick=quick, show_progress=show, config=config)
    ws.write_metrics('drl', metrics)
    dev = metrics['development']['nominal_drift_sech']
    print(f"drl: {metrics['algorithm']} {metrics['steps']} steps in "
          f"{metrics['wall_seconds']:.0f} s; nominal cavity, slow drift from a pulse: O/O* "
          f"{dev['policy_O_over_O_star']:.3f} (holding the start angles "
          f"{dev['hold_O_over_O_star']:.3f}); wrote {ws.models_dir / metrics['file']}",
          flush=True)


def check_estimator(ws: Workspace, out: Path, quick: bool, show: bool) -> None:
    """The identifiability study of the shipped estimator on the datasets."""
    from dlmpc_ros.evaluation.identifiability import ProbeConfig
    from dlmpc_ros.evaluation.identifiability import check_estimator as check
    from dlmpc_ros.learning.vae import load_vae
    from dlmpc_ros.training import shards
    from dlmpc_ros.training.trajectories import load_trajectories

    vae, _ = load_vae(ws.model('vae'))
    check(vae, load_trajectories(ws.trajectories), shards.load_dataset(ws.sweep), out,
          ProbeConfig(epochs=2 if quick else 40), show_progress=show)
    print(f'check-estimator: report in {out}/report.md', flush=True)


def adapt(args: argparse.Namespace, show: bool) -> int:
    """Calibrate the models to the laser of ``--bag``; writes ``--out``."""
    from dlmpc_ros.training.adapt import AdaptConfig, adapt_models
    from dlmpc_ros.training.adapt_estimator import EstimatorAdaptConfig
    if args.bag is None or args.out is None:
        print('dlmpc-train adapt: give --bag DIR (a run of `bringup --controller explore '
              '--record DIR`) and --out MODELS', file=sys.stderr)
        return 2
    estimator = (None if not args.laser_estimator else
                 EstimatorAdaptConfig(epochs=2, map_steps=100, min_windows=50) if args.quick else
                 EstimatorAdaptConfig())
    report = adapt_models(args.bag, args.models_dir, args.out,
                          AdaptConfig(round_trips=args.round_trips, seed=args.seed,
                                      fine_tune=args.fine_tune,
                                      epochs=4 if args.quick else AdaptConfig.epochs,
                                      estimator=estimator,
                                      measurement_round_trips=args.measurement_round_trips),
                          show_progress=show)
    estimate = report['estimator']
    print(f"adapt: {report['pairs']} pairs to fit and {report['held_out_pairs']} held out "
          f"(the run's last periods) from {report['control_periods']} control periods "
          f"({report['round_trips_used']} round trips); predictor RMSE on the held-out pairs "
          f"{report['held_out_rmse_before']:.4f}, corrected "
          f"{report['held_out_rmse_corrected']:.4f} (correction "
          f"{[round(c, 4) for c in report['correction']]}; all 0: none kept)"
          + (f", fine-tuned {report['held_out_rmse_after']:.4f} (members kept at epochs "
             f"{report['epochs_kept']}; 0: shipped)" if args.fine_tune else '')
          + f"; rotation prior at "
          f"{report['prior_knots_set']} knots; estimator and map "
          + (f"learned on {estimate['windows']} windows of {estimate['window']} periods "
             f"(loss {estimate['train_loss']:.2f}, on the {estimate['held_out_windows']} "
             f"held out {estimate['held_out_loss']:.2f})" if estimate['kept']
             else f"shipped ({estimate['why']})")
          + f"; wrote {args.out}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='dlmpc-train', description=__doc__.split('\n\n')[0])
    p.add_argument('stage', choices=STAGES)
    p.add_argument('--data-dir', type=Path, default=Path('data'))
    p.add_argument('--models-dir', type=Path, default=Path('models'))
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--out', type=Path,
                   help='check-estimator: where its report goes (default '
                        'out/estimator-check); adapt: the calibrated models folder')
    p.add_argument('--quick', action='store_true', help='tiny training runs for tests')
    p.add_argument('--no-progress', action='store_true')
    p.add_argument('--bag', type=Path, help='adapt: the recorded bag of the laser')
    p.add_argument('--round-trips', type=int, default=0,
                   help='adapt: use the first N round trips of the bag (0: all)')
    p.add_argument('--fine-tune', action='store_true',
                   help='adapt: also fine-tune the predictor on the bag (measured to plan '
                        'worse; the correction alone is the default)')
    p.add_argument('--laser-estimator', action='store_true',
                   help="adapt: also learn this laser's own estimator and map from the bag's "
                        'windows of measurements (measured to do worse in closed loop than '
                        'the shipped ones: bench/results/laser_estimator.md)')
    p.add_argument('--measurement-round-trips', type=int, default=MEASUREMENT_ROUND_TRIPS,
                   help='adapt: round trips a period\'s measurement averages, as the '
                        f'controller\'s parameter (default {MEASUREMENT_ROUND_TRIPS})')
    p.add_argument('--algorithm', choices=('ppo', 'sac'),
                   help='drl: the algorithm (default: ppo, measured the better here; '
                        'docs/gym.md)')
    p.add_argument('--steps', type=int, default=0,
                   help='drl: env steps of training (0: the default, 300,000)')
    p.add_argument('--workers', type=int, default=default_workers(),
                   help='response: simulate its data on this many local Dask workers '
                        '(default: the cores)')
    args = p.parse_args(argv)
    ws = Workspace(args.data_dir, args.models_dir)
    show = not args.no_progress
    started = time.monotonic()
    try:
        if args.stage == 'check-estimator':
            check_estimator(ws, args.out or Path('out/estimator-check'), args.quick, show)
            return 0
        if args.stage == 'adapt':
            return adapt(args, show)
        run_stages(args.stage, ws, args.seed, args.quick, show, args.workers,
                   drl={'algorithm': args.algorithm, 'total_steps': args.steps})
    except (FileNotFoundError, ModelFileError, ValueError) as err:
        print(f'dlmpc-train: {err}', file=sys.stderr)
        return 2
    if args.stage != 'curve':  # the curve alone reads only models/; the card needs data/
        from dlmpc_ros.training.card import write_model_card
        write_model_card(ws)
    print(json.dumps({'wall_seconds': round(time.monotonic() - started, 1)}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
