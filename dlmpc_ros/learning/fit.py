"""The one mini-batch training loop every model uses (Adam, seeded order, progress bar)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import torch
from tqdm import tqdm


class Batches(Protocol):
    """A dataset that cuts its own mini-batches (e.g. windows of trajectories)."""

    def __len__(self) -> int: ...

    def batch(self, index: torch.Tensor) -> Any: ...


#: ``loss_fn(batch, generator) -> (loss, extra figures)``.
LossFn = Callable[[Any, torch.Generator], tuple[torch.Tensor, dict]]


def fit(model: torch.nn.Module, loss_fn: LossFn, data: np.ndarray | torch.Tensor | Batches,
        epochs: int, batch: int = 512, lr: float = 1e-3, seed: int = 0, *,
        cosine: bool = False, clip_norm: float = 0.0,
        on_epoch: Callable[[int, float], None] | None = None, desc: str = 'training',
        show_progress: bool = True) -> list[float]:
    """Adam over shuffled mini-batches of ``data``; returns the mean loss of each epoch.

    Parameters
    ----------
    data
        Samples along the first axis (an array or tensor, taken as float32), or a
        :class:`Batches` whose ``batch(index)`` cuts the samples ``index``.
    epochs, batch, lr
        Passes over the data, samples per Adam step and the learning rate.
    seed
        Seed of the generator that orders the samples and is passed to ``loss_fn``.
    cosine
        Decay the learning rate to 0 along a half cosine over all steps (per step).
    clip_norm
        Clip the gradient norm to this per step (0: no clipping).
    on_epoch
        Called as ``on_epoch(epoch, mean_loss)`` after each epoch.
    """
    generator = torch.Generator().manual_seed(seed)
    if isinstance(data, (np.ndarray, torch.Tensor)):
        tensor = torch.as_tensor(data, dtype=torch.float32)
        n_samples, take = tensor.shape[0], tensor.__getitem__
    else:
        n_samples, take = len(data), data.batch
    if n_samples == 0:
        raise ValueError('no training samples')
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    steps_per_epoch = -(-n_samples // batch)
    schedule = (torch.optim.lr_scheduler.CosineAnnealingLR(optimizer,
                                                           T_max=epochs * steps_per_epoch)
                if cosine and epochs > 0 else None)
    history: list[float] = []
    bar = tqdm(range(epochs), desc=desc, disable=not show_progress, unit='epoch')
    for epoch in bar:
        order = torch.randperm(n_samples, generator=generator)
        total = 0.0
        model.train()
        for start in range(0, n_samples, batch):
            index = order[start:start + batch]
            optimizer.zero_grad()
            loss, _ = loss_fn(take(index), generator)
            loss.backward()
            if clip_norm > 0:
                torch.nn.utils.clip_grad_norm_(model.parameters(), clip_norm)
            optimizer.step()
            if schedule is not None:
                schedule.step()
            total += float(loss.detach()) * len(index)
        history.append(total / n_samples)
        bar.set_postfix(loss=f'{history[-1]:.4f}')
        if on_epoch is not None:
            on_epoch(epoch, history[-1])
    model.eval()
    return history
