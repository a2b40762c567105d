"""The DL-MPC's steady-response predictor: what turning the tracking curve does to O.

From the curve point ``u``, its rotation ``theta`` and the measured ``E`` and ``M`` it predicts
the settled change of log O of a further turn ``delta``: an ensemble of small networks on
bootstrap samples, whose spread says where a plan leaves the data. Trained on plants drawn
from the family, never on K (:mod:`dlmpc_ros.training.stages.response`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import nn

from dlmpc_ros.learning.seeding import reset_linear_layers

if TYPE_CHECKING:  # its file's settings
    from dlmpc_ros.learning.response_file import ResponseModelConfig

#: The predictor's inputs, in order: curve parameter (K units), rotation [rad], log E,
#: log M, the further turn [rad].
FEATURES = ('u', 'theta', 'log_E', 'log_M', 'delta')


class ResponseEnsemble(nn.Module):
    """Inputs (..., 5) of :data:`FEATURES` -> predicted change of log O (..., members);
    ``generator`` (optional) draws the initial weights."""

    def __init__(self, config: ResponseModelConfig,
                 generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.config = config
        self.members = nn.ModuleList(_network(config) for _ in range(config.members))
        self.register_buffer('mean', torch.tensor(config.mean, dtype=torch.float32))
        self.register_buffer('std', torch.tensor(config.std, dtype=torch.float32))
        if generator is not None:
            reset_linear_layers(self, generator)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = (x - self.mean) / self.std
        return torch.cat([member(z) for member in self.members], dim=-1)

    @torch.no_grad()
    def predict(self, u: float, theta: float, energy: float, kurtosis: float,
                delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and spread over the members (each (n,)) of the change of log O after the
        further turns ``delta`` (n,) [rad], from the state ``(u, theta, E, M)``."""
        delta = np.asarray(delta, float)
        x = np.empty((delta.size, len(FEATURES)), np.float32)
        x[:, :4] = (u, theta, np.log(energy), np.log(kurtosis))
        x[:, 4] = delta
        out = self(torch.from_numpy(x)).numpy()
        return out.mean(axis=1), out.std(axis=1)


def _network(config: ResponseModelConfig) -> nn.Sequential:
    sizes = [len(FEATURES)] + [config.hidden] * (config.layers - 1)
    blocks: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:]):
        blocks += [nn.Linear(a, b), nn.Tanh()]
    return nn.Sequential(*blocks, nn.Linear(sizes[-1], 1))

