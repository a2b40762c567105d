"""Model files: state_dict + config + metrics + data fingerprint + schema version.

Files are written with ``torch.save`` of plain containers and read back with
``torch.load(weights_only=True)``, which refuses anything but tensors and primitive
containers: loading a model never executes code from the file.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from dlmpc_ros.learning.model_files import KINDS, ModelFileError, regenerate_hint

SCHEMA_VERSION = 1
__all__ = ['KINDS', 'ModelFileError', 'SCHEMA_VERSION', 'load_checkpoint', 'load_model',
           'regenerate_hint', 'save_checkpoint']


def save_checkpoint(path: str | Path, kind: str, state_dict: dict[str, torch.Tensor],
                    config: dict[str, Any], metrics: dict[str, Any],
                    fingerprint: str) -> Path:
    """Write a model file; ``kind`` is one of :data:`KINDS`."""
    if kind not in KINDS:
        raise ValueError(f'unknown model kind {kind!r}; one of {tuple(KINDS)}')
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {'schema_version': SCHEMA_VERSION, 'kind': kind,
               'state_dict': {k: v.detach().cpu().clone() for k, v in state_dict.items()},
               'config': config, 'metrics': metrics, 'data_fingerprint': fingerprint}
    tmp = path.with_suffix(path.suffix + '.tmp')
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_checkpoint(path: str | Path, kind: str) -> dict[str, Any]:
    """Read a model file without executing code; raises :class:`ModelFileError` with a
    message that says how to regenerate the file."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f'model file {path} is missing; {regenerate_hint(kind)}')
    try:
        payload = torch.load(path, map_location='cpu', weights_only=True)
    except Exception as err:  # truncated, not a torch file, or disallowed content
        raise ModelFileError(f'model file {path} is corrupt or not a dlmpc_ros model '
                             f'({type(err).__name__}); {regenerate_hint(kind)}') from None
    if not isinstance(payload, dict) or payload.get('kind') != kind:
        found = payload.get('kind') if isinstance(payload, dict) else type(payload).__name__
        raise ModelFileError(f'model file {path} holds {found!r}, not a {kind} model; '
                             f'{regenerate_hint(kind)}')
    if payload.get('schema_version') != SCHEMA_VERSION:
        raise ModelFileError(f'model file {path} has schema {payload.get("schema_version")}, '
                             f'this version reads {SCHEMA_VERSION}; {regenerate_hint(kind)}')
    return payload


def load_model(path: str | Path, kind: str, build: Callable[[dict[str, Any]], torch.nn.Module]
               ) -> tuple[torch.nn.Module, dict[str, Any]]:
    """A model rebuilt from its file, in eval mode, and the file's payload.

    ``build(config)`` makes the untrained model from the stored config dict; its weights
    are then loaded. Raises :class:`ModelFileError` when the file is missing or corrupt,
    holds another kind, or does not fit this version's model.
    """
    payload = load_checkpoint(path, kind)
    try:
        model = build(payload['config'])
        model.load_state_dict(payload['state_dict'])
    except (KeyError, TypeError, ValueError, RuntimeError, AttributeError) as err:
        first = (str(err).splitlines() or [''])[0]
        raise ModelFileError(f'model file {path} does not hold a valid {KINDS[kind]} for this '
                             f'version ({type(err).__name__}: {first}); '
                             f'{regenerate_hint(kind)}') from None
    return model.eval(), payload
