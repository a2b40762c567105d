"""Angle tables over the K grid and their files (numpy; plain .npz, no pickles).

- the oracle envelope (``data/oracle.npz``, made by ``dlmpc-data oracle``): ``K`` (n_k,),
  ``O_star`` (n_k,) the best steady objective found at each K and ``angles`` (n_k, 4)
  [rad] where it was found, with the search's own figures;
- the baseline tables (``models/oracle.npz``, made by ``dlmpc-train baselines``): the
  envelope's ``K``, ``O_star`` and ``angles`` plus the fixed-best angle set and the
  branch-continuous tracking path (:data:`REQUIRED_KEYS`); evaluation divides by its
  ``O_star``, the baseline controllers read their angles from it.

Made by :mod:`dlmpc_ros.training.envelope` and
:mod:`dlmpc_ros.training.baseline_tables`.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

#: Arrays every baselines file holds (others may be added).
REQUIRED_KEYS = ('K', 'O_star', 'angles', 'tracking_angles', 'tracking_O', 'fixed_best_angles',
                 'fixed_best_worst_O', 'fixed_best_mean_O')
SCHEMA_VERSION = 1
BASELINES_HINT = 'run `dlmpc-train baselines` to make it'


def read_npz(path: Path, what: str, hint: str) -> dict[str, np.ndarray]:
    """Every array of a plain .npz file (no pickles are loaded).

    Raises FileNotFoundError when it is missing and ValueError when it cannot be read; both
    name ``what`` the file is and end with ``hint`` (how to make it)."""
    path = Path(path)
    if not path.is_file():
        verb = 'are' if what.endswith('s') else 'is'
        raise FileNotFoundError(f'{what} {path} {verb} missing; {hint}')
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile) as err:
        raise ValueError(f'{what} {path} cannot be read ({err}); {hint}') from None


def write_npz(path: Path, arrays: dict[str, np.ndarray], meta: dict | None = None) -> Path:
    """Write ``arrays`` to ``path`` atomically (.npz, plain arrays) and ``meta``, if given,
    beside it (.json)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + '.tmp.npz')
    np.savez(tmp, **{k: np.asarray(v) for k, v in arrays.items()})
    tmp.replace(path)
    if meta is not None:
        path.with_suffix('.json').write_text(json.dumps(meta, indent=2, default=float))
    return path


# -- the oracle envelope ---------------------------------------------------------------------

def load_envelope(path: Path) -> dict[str, np.ndarray]:
    """The envelope arrays of ``path`` (``data/oracle.npz`` or ``models/oracle.npz``)."""
    return read_npz(path, 'oracle envelope', 'run `dlmpc-data oracle`')


def envelope_angles(envelope: dict[str, np.ndarray], k: np.ndarray) -> np.ndarray:
    """Oracle angles at the grid K nearest to each ``k``, (..., 4)."""
    k = np.asarray(k, float)
    index = np.abs(envelope['K'][None, :] - k.reshape(-1, 1)).argmin(axis=1)
    return envelope['angles'][index].reshape(*k.shape, 4)


def envelope_objective(envelope: dict[str, np.ndarray], k: np.ndarray) -> np.ndarray:
    """O*(K) linearly interpolated over the grid."""
    return np.interp(np.asarray(k, float), envelope['K'], envelope['O_star'])


# -- the baseline tables -----------------------------------------------------------------------

def save_baselines(path: Path, arrays: dict[str, np.ndarray], meta: dict) -> Path:
    """Write the baseline tables to ``path`` (.npz) and ``meta`` beside it (.json)."""
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise ValueError(f'baselines lack {missing}')
    return write_npz(path, arrays, meta)


def load_baselines(path: Path) -> dict[str, np.ndarray]:
    """The baseline tables of ``path`` (models/oracle.npz) as a dict of arrays.

    Raises FileNotFoundError when the file is missing and ValueError when it cannot be
    read or lacks one of :data:`REQUIRED_KEYS`; both say to run ``dlmpc-train baselines``.
    """
    path = Path(path)
    arrays = read_npz(path, 'baseline tables', BASELINES_HINT)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise ValueError(f'baseline tables {path} lack {missing} (an older or foreign file); '
                         f'{BASELINES_HINT}')
    return arrays
