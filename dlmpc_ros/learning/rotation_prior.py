"""``rotation_prior.npz``: the rotation of the tracking curve a calibrated models folder
starts from (``dlmpc-train adapt``, :mod:`dlmpc_ros.training.adapt`).

It holds ``knots`` (n,), curve parameters in K's units, and ``values`` (n,), the rotation
[rad] at each, plus ``schema_version``; a ``.json`` note beside it says which bag it was
calibrated from. Without the file the controller starts from the curve as it was made
(rotation 0). No value in it is a K or a plant parameter: it is learned from E, M and the
angles of the laser's own run.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.learning.tables import read_npz, write_npz

SCHEMA_VERSION = 1
FILE_NAME = 'rotation_prior.npz'
HINT = 'remake it with `dlmpc-train adapt --bag DIR`, or delete it to start from rotation 0'


def save_rotation_prior(models_dir: Path, knots: np.ndarray, values: np.ndarray,
                        note: dict) -> Path:
    """Write the prior into ``models_dir`` (and its note beside it)."""
    return write_npz(Path(models_dir) / FILE_NAME,
                     {'knots': np.asarray(knots, float), 'values': np.asarray(values, float),
                      'schema_version': np.array(SCHEMA_VERSION)}, note)


def load_rotation_prior(models_dir: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """``(knots, values)`` of ``models_dir``'s prior, checked; None when it has none.
    Raises ValueError for a file that cannot be read or is malformed."""
    path = Path(models_dir) / FILE_NAME
    if not path.exists():
        return None
    arrays = read_npz(path, 'rotation prior', HINT)
    knots, values = arrays.get('knots'), arrays.get('values')
    if knots is None or values is None or int(arrays.get('schema_version', -1)) != \
            SCHEMA_VERSION or knots.ndim != 1 or knots.shape != values.shape \
            or knots.size < 2 or not np.all(np.diff(knots) > 0) \
            or not np.all(np.isfinite(values)):
        raise ValueError(f'rotation prior {path} is malformed; {HINT}')
    return knots.astype(float), values.astype(float)
