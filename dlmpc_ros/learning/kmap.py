"""The K-to-angles map (paper section 3C): a small fully connected network from the K
surrogate to good angles.

The network predicts ``(sin 2 alpha, cos 2 alpha)`` (pi-periodic angles without a
wrap-around). Its training pairs and fit are :mod:`dlmpc_ros.training.stages.kmap`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import nn

from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import load_model
from dlmpc_ros.learning.features import angles_from_features
from dlmpc_ros.learning.seeding import reset_linear_layers


@dataclass(frozen=True)
class KMapConfig:
    """Sizes of the map (stored in its file)."""

    hidden: int = 64
    """Units of every hidden layer."""
    layers: int = 3
    """Linear layers (ReLU between them)."""

    def __post_init__(self) -> None:
        checks.counts(self, 'hidden', 'layers')

    def to_dict(self) -> dict:
        return asdict(self)


class KMap(nn.Module):
    """Surrogate (..., 1) -> angles (..., 4) in radians, in [-pi/2, pi/2).

    ``generator`` (optional) draws the initial weights (PyTorch's default scheme).
    """

    def __init__(self, config: KMapConfig, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.config = config
        sizes = [1] + [config.hidden] * (config.layers - 1)
        blocks: list[nn.Module] = []
        for a, b in zip(sizes[:-1], sizes[1:]):
            blocks += [nn.Linear(a, b), nn.ReLU()]
        self.net = nn.Sequential(*blocks, nn.Linear(sizes[-1], 8))
        if generator is not None:
            reset_linear_layers(self, generator)

    def features(self, s: torch.Tensor) -> torch.Tensor:
        """(..., 8) predicted sin/cos features."""
        return self.net(s)

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return angles_from_features(self.features(s))


def load_kmap(path: str | Path) -> tuple[KMap, dict]:
    """The K-to-angles map and its file's payload; raises
    :class:`~dlmpc_ros.learning.checkpoint.ModelFileError`."""
    return load_model(path, 'kmap', lambda config: KMap(KMapConfig(**config)))
