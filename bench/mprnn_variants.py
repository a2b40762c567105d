"""Ablation of the MP-RNN predictor: each variant trained by ``dlmpc-train mprnn``'s own code.

A variant overrides fields of :class:`~dlmpc_ros.learning.mprnn.MPRNNConfig` (``model``) and
of the stage's :class:`~dlmpc_ros.training.predictor.TrainConfig` (``train``, over
:data:`~dlmpc_ros.training.stages.mprnn.FULL`); a variant with no overrides reproduces the
shipped training. Nothing is saved into the models directory
(its VAE and K-map are read). Variants are chosen on the validation lanes (the first half
of the held-out trajectories); the test lanes are the second half, as in the model card.

Usage::

    python bench/mprnn_variants.py --variants variants.json --data-dir data \\
        --models-dir models --out bench/results/mprnn_variants.json

``variants.json`` maps names to overrides, e.g. ``{"shipped": {}, "cosine": {"train":
{"cosine": true}}, "wide": {"model": {"n_hidden": 128}}, "more data":
{"extra_trajectories": ["data/trajectories_extra"]}}`` (extra directories add their
training lanes). Writes every variant's metrics
as JSON and a markdown table of the O error at horizons 1, 5 and 10 relative to
persistence beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def ratios(model: list[float], persistence: list[float]) -> list[float]:
    return [m / p for m, p in zip(model, persistence)]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--variants', type=Path, required=True)
    p.add_argument('--data-dir', type=Path, default=ROOT / 'data')
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--only', nargs='*', help='run only these variants')
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)

    from dlmpc_ros.learning.kmap import load_kmap
    from dlmpc_ros.learning.mprnn import MPRNNConfig
    from dlmpc_ros.learning.vae import load_vae
    from dlmpc_ros.training.predictor import TrainConfig
    from dlmpc_ros.training.stages.mprnn import FULL, predictor_data, train_predictor
    from dlmpc_ros.training.workspace import Workspace

    variants = json.loads(args.variants.read_text())
    ws = Workspace(args.data_dir, args.models_dir)
    vae, _ = load_vae(ws.model('vae'))
    kmap, _ = load_kmap(ws.model('kmap'))
    results = json.loads(args.out.read_text()) if args.out.exists() else {}
    for name, overrides in variants.items():
        if args.only and name not in args.only:
            continue
        started = time.monotonic()
        data = predictor_data(ws, vae, tuple(Path(d) for d in
                                             overrides.get('extra_trajectories', ())))
        config = MPRNNConfig(**{'norm': vae.config.normalizer, **overrides.get('model', {})})
        train_cfg = TrainConfig(**{**FULL.__dict__, 'seed': args.seed,
                                   **overrides.get('train', {})})
        _, metrics = train_predictor(data, kmap, config, train_cfg, args.seed)
        results[name] = {'overrides': overrides, 'wall_seconds': round(
            time.monotonic() - started, 1), **metrics}
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1, default=float))
        test = ratios(metrics['rmse_O_model'], metrics['rmse_O_persistence'])[-1]
        val = ratios(metrics['validation_rmse_O_model'],
                     metrics['validation_rmse_O_persistence'])[-1]
        print(f"{name}: horizon-10 O error / persistence = {test:.3f} (test), {val:.3f} "
              f"(validation), {results[name]['wall_seconds']:.0f} s", flush=True)
    lines = ['# MP-RNN variants', '',
             f'`python bench/mprnn_variants.py --variants {args.variants.name}` (seed '
             f'{args.seed}). O RMSE relative to persistence at horizons 1 / 5 / 10; validation '
             'lanes chose, test lanes measure.', '',
             '| variant | overrides | validation h1 / h5 / h10 | test h1 / h5 / h10 | '
             'chosen stage | wall s |', '|---|---|---|---|---|---|']
    for name, r in results.items():
        val = ratios(r['validation_rmse_O_model'], r['validation_rmse_O_persistence'])
        test = ratios(r['rmse_O_model'], r['rmse_O_persistence'])
        pick = ' / '.join
        lines.append(f"| {name} | `{json.dumps(r['overrides'])}` | "
                     f"{pick(f'{val[i]:.3f}' for i in (0, 4, 9))} | "
                     f"{pick(f'{test[i]:.3f}' for i in (0, 4, 9))} | "
                     f"{r['chosen_after_stage']} | {r['wall_seconds']:.0f} |")
    args.out.with_suffix('.md').write_text('\n'.join(lines) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
