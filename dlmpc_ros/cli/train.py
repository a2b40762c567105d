"""dlmpc-train: train, measure and ship the models (estimator, map, predictor).

``dlmpc-train all`` runs ``vae``, ``kmap``, ``mprnn``, ``baselines`` and ``curve`` in order
on the datasets of ``dlmpc-data`` and writes ``models/{vae,kmap,mprnn}.pt``, the baseline
angle tables ``models/oracle.npz`` (+ ``.json``), the DL-MPC's tracking curve
``models/track_curve.npz`` (from the baseline tables; ``curve`` alone remakes it from the
shipped ``oracle.npz`` in a second), ``models/metrics.json``, ``models/figures/`` and
``models/MODEL_CARD.md``. ``--quick`` trains tiny models for tests.
``check-estimator`` measures where the shipped estimator's surrogate gets its information
(angles or E and M; needs true K, so it is an evaluation) and writes a report to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from dlmpc_ros.learning.checkpoint import ModelFileError
from dlmpc_ros.learning.pipeline import (Paths, train_kmap_stage, train_vae_stage,
                                         write_metrics)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog='dlmpc-train', description=__doc__.split('\n\n')[0])
    p.add_argument('stage', choices=('all', 'vae', 'kmap', 'mprnn', 'baselines', 'curve',
                                     'check-estimator'))
    p.add_argument('--data-dir', type=Path, default=Path('data'))
    p.add_argument('--models-dir', type=Path, default=Path('models'))
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--out', type=Path, default=Path('out/estimator-check'),
                   help='check-estimator: where its report goes')
    p.add_argument('--quick', action='store_true', help='tiny training runs for tests')
    p.add_argument('--no-progress', action='store_true')
    args = p.parse_args(argv)
    paths = Paths(args.data_dir, args.models_dir)
    show = not args.no_progress
    started = time.monotonic()
    try:
        if args.stage in ('all', 'vae'):
            metrics = train_vae_stage(paths, args.seed, epochs=2 if args.quick else 25,
                                      show_progress=show)
            write_metrics(paths, 'vae', metrics)
            print(f"vae: |r| = {metrics['abs_pearson_r_heldout']:.3f} (window "
                  f"{metrics['chosen_window']})", flush=True)
        if args.stage in ('all', 'kmap'):
            metrics = train_kmap_stage(paths, args.seed, steps=200 if args.quick else 3000,
                                       show_progress=show)
            write_metrics(paths, 'kmap', metrics)
            print(f"kmap: O/O* = {metrics['oracle_ratio_test_k']:.3f} (test K)", flush=True)
        if args.stage in ('all', 'mprnn'):
            from dlmpc_ros.learning.pipeline_mprnn import train_mprnn_stage
            metrics = train_mprnn_stage(paths, args.seed, quick=args.quick, show_progress=show,
                                        extra_trajectories=(paths.extra_trajectories,))
            write_metrics(paths, 'mprnn', metrics)
            print(f"mprnn: horizon-{len(metrics['rmse_O_model'])} O error / persistence = "
                  f"{metrics['rmse_O_model'][-1] / metrics['rmse_O_persistence'][-1]:.3f}",
                  flush=True)
        if args.stage in ('all', 'baselines'):
            from dlmpc_ros.learning.baselines import train_baselines_stage
            metrics = train_baselines_stage(paths, quick=args.quick, show_progress=show)
            write_metrics(paths, 'baselines', metrics)
            first = next(iter(metrics['closed_loop']))
            ratios = {name: round(r['oracle_ratio'], 3)
                      for name, r in metrics['closed_loop'][first].items()}
            print(f'baselines: closed-loop O/O* on {first}: {ratios}', flush=True)
        if args.stage in ('all', 'baselines', 'curve'):
            from dlmpc_ros.learning.track_curve import train_curve_stage
            metrics = train_curve_stage(paths.models_dir)
            write_metrics(paths, 'curve', metrics)
            print(f"curve: {metrics['points']} points, mean steady O "
                  f"{metrics['mean_objective']:.4f}", flush=True)
        if args.stage == 'check-estimator':
            from dlmpc_ros.learning.identifiability import ProbeConfig, check_estimator
            check_estimator(paths, args.out, ProbeConfig(epochs=2 if args.quick else 40),
                            show_progress=show)
            print(f'check-estimator: report in {args.out}/report.md', flush=True)
            return 0
    except (FileNotFoundError, ModelFileError, ValueError) as err:
        print(f'dlmpc-train: {err}', file=sys.stderr)
        return 2
    if args.stage != 'curve':  # the curve alone reads only models/; the card needs data/
        from dlmpc_ros.learning.card import write_model_card
        write_model_card(paths)
    print(json.dumps({'wall_seconds': round(time.monotonic() - started, 1)}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
