"""A small MP-RNN config and random inputs shared by the model and training tests."""

from __future__ import annotations

import torch

from dlmpc_ros.learning.features import angle_features
from dlmpc_ros.learning.mprnn import MPRNNConfig

CFG = MPRNNConfig(window=2, horizon=4, n_hidden=8, n_latent=6)
N, H = CFG.horizon, CFG.min_history()


def random_inputs(batch: int = 3, seed: int = 0, rows: int = H
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """history (batch, rows, 10), future_u (batch, N, 4), future_x (batch, N, 10)."""
    gen = torch.Generator().manual_seed(seed)
    angles = (torch.rand(batch, rows + N, 4, generator=gen) - 0.5) * torch.pi
    states = torch.randn(batch, rows + N, 2, generator=gen)
    x = torch.cat([states, angle_features(angles)], dim=-1)
    return x[:, :rows], angles[:, rows:], x[:, rows:]
