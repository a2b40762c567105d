"""The ablation's nominal-only pretraining: the steady-response predictor trained on the
nominal cavity alone (no domain randomization over the plant family).

Copies ``--models-dir`` to ``--out``, makes the rotation data of the nominal cavity (the
shipped settings, every "plant" the nominal cavity, so one plant's worth) into
``--out/data`` and trains ``--out/models/response.pt`` from it with the shipped stage;
``bench/dlmpc_variants.py`` then runs it as the variant ``{"models_dir":
"OUT/models"}``::

    python bench/nominal_pretraining.py --out out/nominal-only
"""

from __future__ import annotations

import argparse
import shutil
from dataclasses import replace
from pathlib import Path

from dlmpc_ros.training.response import ResponseConfig
from dlmpc_ros.training.stages.response import train_response_stage
from dlmpc_ros.training.workspace import Workspace

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--models-dir', type=Path, default=ROOT / 'models')
    p.add_argument('--out', type=Path, required=True)
    args = p.parse_args(argv)
    models = args.out / 'models'
    shutil.copytree(args.models_dir, models, dirs_exist_ok=True)
    ws = Workspace(args.out / 'data', models)
    config = replace(ResponseConfig(), plants=1, plants_per_task=1, nominal_only=True)
    metrics = train_response_stage(ws, seed=0, data_cfg=config, closed_loop=False)
    print(f"nominal-only predictor in {models}: RMSE on the family's held-out plants is "
          f"not measured here; its own held-out figure {metrics['heldout_rmse_where_kept']:.4f}")
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
