"""The DL-MPC's tracking curve: the best branch-continuous angles as a 1-D curve.

``models/track_curve.npz`` holds ``grid`` (n,), the curve parameter (a birefringence
estimate on the curve's own axis, in K's units), ``angles`` (n, 4) [rad], continuous
along the grid (pi-equivalents chosen next to each other), and ``objective`` (n,), the
steady O the simulator reached on the curve at each grid point, plus ``schema_version``.
It is made from the refined tracking path of the baseline tables (``models/oracle.npz``)
by ``dlmpc-train curve`` (or at the end of ``dlmpc-train baselines``). The controller
that loads it never learns the true K of a run: the curve is a map from an estimate to
angles, like the K-to-angles map.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from dlmpc_ros.control.tracking import check_curve
from dlmpc_ros.learning.baselines import read_npz, unwrap_table

SCHEMA_VERSION = 1
FILE_NAME = 'track_curve.npz'
HINT = 'run `dlmpc-train curve` (from models/oracle.npz) to make it'


def curve_from_baselines(baselines: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The curve arrays from the baseline tables: the refined tracking path where the
    tables have it (full runs), else the plain tracking path (``--quick`` runs)."""
    key = 'tracking_refined' if 'tracking_refined_angles' in baselines else 'tracking'
    return {'grid': np.asarray(baselines['K'], float),
            'angles': unwrap_table(baselines[f'{key}_angles']),
            'objective': np.asarray(baselines[f'{key}_O'], float),
            'schema_version': np.array(SCHEMA_VERSION)}


def save_curve(path: Path, curve: dict[str, np.ndarray], source: str) -> Path:
    """Write the curve (.npz, plain arrays) and a .json note of how it was made."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + '.tmp.npz')
    np.savez(tmp, **curve)
    tmp.replace(path)
    note = {'schema_version': SCHEMA_VERSION, 'made_by': 'dlmpc-train curve',
            'source': source, 'points': int(curve['grid'].size),
            'mean_objective': float(np.mean(curve['objective']))}
    path.with_suffix('.json').write_text(json.dumps(note, indent=2))
    return path


def load_curve(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(grid (n,), angles (n, 4), objective (n,))`` of a curve file, checked.

    Raises FileNotFoundError when it is missing and ValueError when it cannot be read or
    is malformed; both say how to make it."""
    path = Path(path)
    arrays = read_npz(path, 'tracking curve', HINT)
    grid, angles, objective = (arrays.get(k) for k in ('grid', 'angles', 'objective'))
    if grid is None or angles is None or objective is None \
            or int(arrays.get('schema_version', -1)) != SCHEMA_VERSION:
        raise ValueError(f'tracking curve {path} lacks grid/angles/objective or has another '
                         f'schema; {HINT}')
    try:
        return check_curve(grid, angles, objective)
    except ValueError as err:
        raise ValueError(f'tracking curve {path} is malformed ({err}); {HINT}') from None


def train_curve_stage(models_dir: Path) -> dict:
    """``dlmpc-train curve``: models/oracle.npz -> models/track_curve.npz; its summary."""
    from dlmpc_ros.learning.baselines import load_baselines
    source = Path(models_dir) / 'oracle.npz'
    baselines = load_baselines(source)
    curve = curve_from_baselines(baselines)
    save_curve(Path(models_dir) / FILE_NAME, curve, str(source))
    return {'points': int(curve['grid'].size),
            'mean_objective': float(np.mean(curve['objective'])),
            'refined': 'tracking_refined_angles' in baselines}
