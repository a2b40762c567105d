"""Dataset shards: ``.npz`` arrays plus a JSON metadata file per dataset directory.

A dataset is a directory of ``shard_00000.npz ...`` files and ``metadata.json``. Shards
are written atomically, so an interrupted generation resumes by skipping the shards that
exist (the metadata's settings must match, or the command refuses to mix datasets).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from dlmpc_ros.core.fingerprint import fingerprint_arrays


def shard_path(directory: Path, index: int) -> Path:
    return Path(directory) / f'shard_{index:05d}.npz'


def write_shard(directory: Path, index: int, arrays: dict[str, np.ndarray]) -> Path:
    path = shard_path(directory, index)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + '.tmp.npz')
    np.savez(tmp, **arrays)
    tmp.replace(path)
    return path


def check_metadata(directory: Path, settings: dict[str, Any]) -> None:
    """Create metadata.json with ``settings``, or check an existing one matches them."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    meta_path = directory / 'metadata.json'
    if meta_path.exists():
        existing = json.loads(meta_path.read_text()).get('settings')
        if existing != json.loads(json.dumps(settings)):
            raise ValueError(f'{directory} holds a dataset made with other settings; delete it '
                             'or choose another --data-dir')
    else:
        meta_path.write_text(json.dumps({'settings': settings}, indent=2))


def finish_metadata(directory: Path, extra: dict[str, Any]) -> dict[str, Any]:
    """Add summary fields (and the data fingerprint) to metadata.json; returns it."""
    meta_path = Path(directory) / 'metadata.json'
    meta = json.loads(meta_path.read_text())
    data = load_dataset(directory)
    meta.update(extra)
    meta['fingerprint'] = fingerprint_arrays(data)
    meta['samples'] = int(next(iter(data.values())).shape[0]) if data else 0
    meta_path.write_text(json.dumps(meta, indent=2))
    return meta


def shard_paths(directory: Path) -> list[Path]:
    """The complete shard files of a dataset, in order (no half-written ``.tmp`` files)."""
    return sorted(p for p in Path(directory).glob('shard_*.npz')
                  if not p.name.endswith('.tmp.npz'))


def load_dataset(directory: Path) -> dict[str, np.ndarray]:
    """Concatenate every shard of a dataset along the first axis."""
    paths = shard_paths(directory)
    if not paths:
        raise FileNotFoundError(f'no dataset shards in {directory}; run `dlmpc-data` first')
    parts: dict[str, list[np.ndarray]] = {}
    for path in paths:
        with np.load(path) as shard:
            for key in shard.files:
                parts.setdefault(key, []).append(shard[key])
    return {key: np.concatenate(values) for key, values in parts.items()}


def metadata(directory: Path) -> dict[str, Any]:
    return json.loads((Path(directory) / 'metadata.json').read_text())
