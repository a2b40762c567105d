"""``turn_correction.npz``: what a calibration learned the rotation planner's predictor
gets wrong on one laser (``dlmpc-train adapt``, :mod:`dlmpc_ros.training.adapt`).

It holds ``coefficients`` (3,), the correction ``a + b * d + c * |d|`` (``d``: a turn of
the curve in units of 0.1 rad) of the predicted change of log O that the planner's online
correction (:class:`~dlmpc_ros.control.rotation_planner.OnlineCorrection`) starts from and
is pulled toward, plus ``schema_version``; a ``.json`` note beside it says which bag it was
fit to. Without the file the correction starts from 0. No value in it is a K or a plant
parameter: it is fit to E, M and the angles of the laser's own run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.learning.tables import read_npz, write_npz

SCHEMA_VERSION = 1
FILE_NAME = 'turn_correction.npz'
TERMS = 3
HINT = 'remake it with `dlmpc-train adapt --bag DIR`, or delete it to start from no correction'


def save_turn_correction(models_dir: Path, coefficients: np.ndarray, note: dict) -> Path:
    """Write the correction's coefficients (3,) into ``models_dir`` (and its note)."""
    coefficients = np.asarray(coefficients, float)
    if coefficients.shape != (TERMS,) or not np.all(np.isfinite(coefficients)):
        raise ValueError(f'a turn correction is {TERMS} finite coefficients, got {coefficients}')
    return write_npz(Path(models_dir) / FILE_NAME,
                     {'coefficients': coefficients,
                      'schema_version': np.array(SCHEMA_VERSION)}, note)


def load_turn_correction(models_dir: Path) -> np.ndarray | None:
    """The coefficients (3,) of ``models_dir``'s correction, checked; None when it has
    none. Raises ValueError for a file that cannot be read or is malformed."""
    path = Path(models_dir) / FILE_NAME
    if not path.exists():
        return None
    arrays = read_npz(path, 'turn correction', HINT)
    coefficients = arrays.get('coefficients')
    if coefficients is None or int(arrays.get('schema_version', -1)) != SCHEMA_VERSION \
            or coefficients.shape != (TERMS,) or not np.all(np.isfinite(coefficients)):
        raise ValueError(f'turn correction {path} is malformed; {HINT}')
    return coefficients.astype(float)
