"""Seeded weight initialization: PyTorch's default initialization of linear layers drawn
from a passed-in generator instead of the global one."""

from __future__ import annotations

import math

import torch
from torch import nn


@torch.no_grad()
def reset_linear_layers(module: nn.Module, generator: torch.Generator) -> nn.Module:
    """Re-initialize every ``nn.Linear`` of ``module`` (in registration order) as
    ``nn.Linear.reset_parameters`` does, drawing from ``generator``; returns ``module``.

    With a generator seeded like ``torch.manual_seed(seed)``, the weights equal those a
    module built right after that call would have, without touching the global state.
    """
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
            if layer.bias is not None:
                bound = 1 / math.sqrt(layer.in_features) if layer.in_features > 0 else 0
                nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
    return module
