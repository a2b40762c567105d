"""``dlmpc-train curve``: the DL-MPC's tracking curve (``models/track_curve.npz``) from the
baseline tables: the refined tracking path as a curve of angles over an estimate axis in
K's units (:mod:`dlmpc_ros.learning.curve`). Needs only ``models/oracle.npz``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.core.angles import unwrap_table
from dlmpc_ros.learning.curve import FILE_NAME, SCHEMA_VERSION, save_curve
from dlmpc_ros.learning.tables import load_baselines


def curve_from_baselines(baselines: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The curve arrays from the baseline tables: the refined tracking path where the
    tables have it (full runs), else the plain tracking path (``--quick`` runs)."""
    key = 'tracking_refined' if 'tracking_refined_angles' in baselines else 'tracking'
    return {'grid': np.asarray(baselines['K'], float),
            'angles': unwrap_table(baselines[f'{key}_angles']),
            'objective': np.asarray(baselines[f'{key}_O'], float),
            'schema_version': np.array(SCHEMA_VERSION)}


def train_curve_stage(models_dir: Path) -> dict:
    """models/oracle.npz -> models/track_curve.npz; returns its summary."""
    source = Path(models_dir) / 'oracle.npz'
    baselines = load_baselines(source)
    curve = curve_from_baselines(baselines)
    save_curve(Path(models_dir) / FILE_NAME, curve, str(source))
    return {'points': int(curve['grid'].size),
            'mean_objective': float(np.mean(curve['objective'])),
            'refined': 'tracking_refined_angles' in baselines}
