"""Family plants for the Gymnasium environment that are checked to mode-lock, with their
envelopes: ``plant_source`` of ``ModeLockedLaser-v0`` (docs/gym.md).

A new family seed costs minutes (the mode-lock check of :func:`draw_plant` and the
envelope search of :func:`cached_plant_envelope`, both cached on disk by the plant's
fingerprint); a seed seen before is read back at once. Without it the environment draws
family plants unchecked and without an envelope.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.plants import PlantFamily
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.training.envelope import PlantEnvelopeConfig, cached_plant_envelope, draw_plant


@dataclass(frozen=True)
class CheckedPlants:
    """``plant_source``: family seed -> (plant that mode-locks at every K, its envelope).

    A plain picklable object, so that an asynchronous vector env's workers can take it.
    """

    tables: str
    """The nominal baseline tables the searches start from (``models/oracle.npz``)."""
    family: PlantFamily = field(default_factory=PlantFamily)
    """The family's ranges."""
    settings: PlantEnvelopeConfig = field(default_factory=PlantEnvelopeConfig)
    """The envelope search's settings."""
    cache: str | None = None
    """Cache directory (None: :func:`~dlmpc_ros.training.envelope.cache_dir`)."""

    def __call__(self, seed: int) -> tuple[CavityConfig, dict[str, np.ndarray]]:
        tables = load_baselines(Path(self.tables))
        cache = None if self.cache is None else Path(self.cache)
        plant, _ = draw_plant(self.family, seed, tables, self.settings, cache)
        envelope = cached_plant_envelope(plant, tables, self.settings, cache)
        return plant, {'K': envelope['K'], 'O_star': envelope['O_star']}


def checked_plants(models_dir: str | Path | None = None, family: PlantFamily | None = None,
                   cache: str | Path | None = None) -> CheckedPlants:
    """The checked plants of ``family`` (default ranges), searched from the tables in
    ``models_dir`` (default: the package's models)."""
    from dlmpc_ros.paths import models_dir as default_models
    tables = Path(models_dir) if models_dir is not None else default_models()
    return CheckedPlants(str(tables / 'oracle.npz'), family or PlantFamily(),
                         cache=None if cache is None else str(cache))
