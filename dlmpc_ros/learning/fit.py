"""Mini-batch training loops shared by the models (seeded, with progress bars)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from tqdm import tqdm


def fit(model: torch.nn.Module, loss_fn: Callable[[torch.Tensor, torch.Generator],
                                                  tuple[torch.Tensor, dict]],
        data: np.ndarray, epochs: int, batch: int = 512, lr: float = 1e-3, seed: int = 0,
        desc: str = 'training', show_progress: bool = True) -> list[float]:
    """Adam over shuffled mini-batches of ``data`` (first axis); returns per-epoch losses.

    ``loss_fn(batch, generator)`` returns the loss and a dict of extra figures.
    """
    generator = torch.Generator().manual_seed(seed)
    tensor = torch.as_tensor(data, dtype=torch.float32)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    history = []
    bar = tqdm(range(epochs), desc=desc, disable=not show_progress, unit='epoch')
    for _ in bar:
        order = torch.randperm(tensor.shape[0], generator=generator)
        total, count = 0.0, 0
        model.train()
        for start in range(0, tensor.shape[0], batch):
            chunk = tensor[order[start:start + batch]]
            optimizer.zero_grad()
            loss, _ = loss_fn(chunk, generator)
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * chunk.shape[0]
            count += chunk.shape[0]
        history.append(total / count)
        bar.set_postfix(loss=f'{history[-1]:.4f}')
    model.eval()
    return history
