"""A short content hash of named arrays: what data a model file or a dataset was made from."""

from __future__ import annotations

import hashlib

import numpy as np


def fingerprint_arrays(arrays: dict[str, np.ndarray]) -> str:
    """Short SHA-256 over named arrays (names, dtypes, shapes and bytes)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f'{name}:{a.dtype}:{a.shape};'.encode())
        digest.update(a.tobytes())
    return digest.hexdigest()[:16]
