"""Conditional RBM that pre-trains the input layers of the MP-RNN (stage 1 of 3).

A conditional restricted Boltzmann machine (Taylor, Hinton & Roweis 2007) with Gaussian
visible units (linear, unit variance) and binary logistic hidden units. Visible units are
the flattened current window ``x_{tau-b+1..tau}`` (b rows of 10 features, time-major), the
condition is the flattened past window ``x_{tau-2b+1..tau-b}``; the condition shifts the
biases of both layers (dynamic biases)::

    p(h = 1 | v, c) = sigmoid(W v + B c + b_h)            # W (H, D), B (H, C)
    p(v | h, c)     = Normal(W^T h + A c + b_v, I)          # A (D, C)

Both v and c are standardized (per column, by the statistics of the training windows)
before they enter the machine; the statistics are kept with it, so every method takes raw
feature windows. Training is contrastive divergence CD-1 with a sampled hidden layer and a
mean-field (noise-free) reconstruction of the visibles, with momentum and weight decay.

:func:`pretrain_input_layers` copies the trained input weights into an MP-RNN cell, with
the standardization folded in so that the cell's pre-activations equal the machine's:

- ``cell.cur``  (W_cur,  current branch)            <- W and b_h
- ``cell.lcur`` (W_lcur, long-term current window)  <- W and b_h  (same values)
- ``cell.past`` (W_past, long-term past window)     <- B, bias from the shift of c only

The sum ``W v + B c + b_h`` of the machine is thus split into the ``h_lcur`` and ``h_past``
pre-activations that the cell couples multiplicatively. The visible bias b_v and the
condition-to-visible weights A only serve the pre-training and are not copied.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import torch
from torch import nn

from dlmpc_ros.core import checks
from dlmpc_ros.learning.mprnn import MPRNN

Progress = Callable[[str, int, float], None]


@dataclass(frozen=True)
class CRBMTrainConfig:
    """Settings of CD-1 training."""

    epochs: int = 5
    """Passes over the windows."""
    batch_size: int = 64
    """Windows per update."""
    lr: float = 5e-3
    """Learning rate (Gaussian visibles want a small one)."""
    momentum: float = 0.9
    """Momentum of the parameter updates (0.5 during the first epoch)."""
    weight_decay: float = 2e-4
    """L2 penalty on W, A and B."""
    init_std: float = 0.01
    """Standard deviation of the initial W; A, B and the biases start at zero."""
    max_samples: int | None = 20000
    """Train on a seeded random subset of at most this many windows (None: all)."""
    seed: int = 0
    """Seed of the initialization, the hidden samples and the mini-batch order."""

    def __post_init__(self) -> None:
        checks.counts(self, 'epochs', 'batch_size')
        checks.counts(self, 'seed', minimum=0)
        checks.positive(self, 'lr', 'init_std')
        checks.non_negative(self, 'weight_decay')
        if not 0 <= self.momentum < 1:
            raise ValueError(f'CRBMTrainConfig.momentum must be in [0, 1), got {self.momentum!r}')
        if self.max_samples is not None:
            checks.counts(self, 'max_samples')

    def to_dict(self) -> dict:
        return asdict(self)


def _flat(x: torch.Tensor) -> torch.Tensor:
    """(S, D) from windows (S, rows, features) or (S, D)."""
    x = torch.as_tensor(x, dtype=torch.float32)
    if x.ndim == 3:
        return x.flatten(1)
    if x.ndim != 2:
        raise ValueError(f'windows must be (S, rows, features) or (S, D), got {tuple(x.shape)}')
    return x


class CRBM(nn.Module):
    """Gaussian-Bernoulli conditional RBM (all state in buffers; trained by CD-1, not SGD).

    Parameters
    ----------
    n_visible, n_cond, n_hidden
        D (10 b for the MP-RNN), C (10 b) and H (the cell's N_h).
    init_std
        Standard deviation of the initial visible-hidden weights.
    seed
        Seed of the initial weights.
    """

    def __init__(self, n_visible: int, n_cond: int, n_hidden: int, init_std: float = 0.01,
                 seed: int = 0) -> None:
        super().__init__()
        if min(n_visible, n_cond, n_hidden) < 1:
            raise ValueError('CRBM sizes must be >= 1')
        gen = torch.Generator().manual_seed(seed)
        w = torch.randn(n_hidden, n_visible, generator=gen) * init_std
        self.register_buffer('weight', w)                               # W (H, D)
        self.register_buffer('cond_hidden', torch.zeros(n_hidden, n_cond))  # B (H, C)
        self.register_buffer('cond_visible', torch.zeros(n_visible, n_cond))  # A (D, C)
        self.register_buffer('visible_bias', torch.zeros(n_visible))
        self.register_buffer('hidden_bias', torch.zeros(n_hidden))
        self.register_buffer('v_mean', torch.zeros(n_visible))
        self.register_buffer('v_std', torch.ones(n_visible))
        self.register_buffer('c_mean', torch.zeros(n_cond))
        self.register_buffer('c_std', torch.ones(n_cond))

    # -- standardization ----------------------------------------------------------------
    def set_standardization(self, v: torch.Tensor, cond: torch.Tensor) -> None:
        """Column means and standard deviations of raw windows v (S, D) and cond (S, C)."""
        v, cond = _flat(v), _flat(cond)
        self.v_mean.copy_(v.mean(0))
        self.v_std.copy_(v.std(0).clamp_min(1e-3))
        self.c_mean.copy_(cond.mean(0))
        self.c_std.copy_(cond.std(0).clamp_min(1e-3))

    def _standardize(self, v: torch.Tensor, cond: torch.Tensor
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        v, cond = _flat(v), _flat(cond)
        if v.shape[1] != self.weight.shape[1] or cond.shape[1] != self.cond_hidden.shape[1]:
            raise ValueError(f'CRBM expects {self.weight.shape[1]} visible and '
                             f'{self.cond_hidden.shape[1]} condition values, got '
                             f'{v.shape[1]} and {cond.shape[1]}')
        return (v - self.v_mean) / self.v_std, (cond - self.c_mean) / self.c_std

    # -- conditionals (standardized units) ----------------------------------------------
    def hidden_probs(self, v_s: torch.Tensor, c_s: torch.Tensor) -> torch.Tensor:
        """(S, H) p(h = 1 | v, c) of standardized v (S, D) and c (S, C)."""
        return torch.sigmoid(v_s @ self.weight.T + c_s @ self.cond_hidden.T + self.hidden_bias)

    def visible_mean(self, h: torch.Tensor, c_s: torch.Tensor) -> torch.Tensor:
        """(S, D) mean of p(v | h, c) (standardized units) of hidden states h (S, H)."""
        return h @ self.weight + c_s @ self.cond_visible.T + self.visible_bias

    @torch.no_grad()
    def reconstruct(self, v: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """(S, D) deterministic mean-field reconstruction of raw windows, in raw units."""
        v_s, c_s = self._standardize(v, cond)
        recon = self.visible_mean(self.hidden_probs(v_s, c_s), c_s)
        return recon * self.v_std + self.v_mean

    @torch.no_grad()
    def reconstruction_error(self, v: torch.Tensor, cond: torch.Tensor) -> float:
        """Mean squared error of the mean-field reconstruction, in standardized units.

        ``v`` and ``cond`` are raw windows (S, b, 10) or flattened (S, D) / (S, C). The
        hidden layer is its probabilities (no sampling), so the value is deterministic; a
        machine that has learnt nothing scores about 1 (the variance of each column).
        """
        v_s, c_s = self._standardize(v, cond)
        recon = self.visible_mean(self.hidden_probs(v_s, c_s), c_s)
        return float(((recon - v_s) ** 2).mean())

    # -- training -----------------------------------------------------------------------
    @torch.no_grad()
    def fit(self, v: torch.Tensor, cond: torch.Tensor, config: CRBMTrainConfig | None = None,
            progress: Progress | None = None) -> list[float]:
        """Train by CD-1 on raw windows; sets the standardization from them first.

        Returns the mean reconstruction error (standardized units) of each epoch, measured
        on the mini-batches as they are trained. ``progress(stage, epoch, value)`` is called
        after each epoch with stage ``'crbm'``.
        """
        config = config or CRBMTrainConfig()
        gen = torch.Generator().manual_seed(config.seed)
        v, cond = _flat(v), _flat(cond)
        if v.shape[0] != cond.shape[0] or v.shape[0] < 2:
            raise ValueError(f'need as many (>= 2) visible as condition windows, got '
                             f'{v.shape[0]} and {cond.shape[0]}')
        if config.max_samples is not None and v.shape[0] > config.max_samples:
            keep = torch.randperm(v.shape[0], generator=gen)[:config.max_samples]
            v, cond = v[keep], cond[keep]
        self.set_standardization(v, cond)
        v_s, c_s = self._standardize(v, cond)
        params = [self.weight, self.cond_hidden, self.cond_visible, self.visible_bias,
                  self.hidden_bias]
        velocity = [torch.zeros_like(p) for p in params]
        decayed = (True, True, True, False, False)
        history: list[float] = []
        for epoch in range(config.epochs):
            momentum = 0.5 if epoch == 0 else config.momentum
            order = torch.randperm(v_s.shape[0], generator=gen)
            total = 0.0
            for start in range(0, len(order), config.batch_size):
                idx = order[start:start + config.batch_size]
                grads, err = self._cd1_gradients(v_s[idx], c_s[idx], gen)
                total += err * len(idx)
                for p, vel, g, dec in zip(params, velocity, grads, decayed):
                    if dec:
                        g = g - config.weight_decay * p
                    vel.mul_(momentum).add_(g, alpha=config.lr)
                    p.add_(vel)
            history.append(total / len(order))
            if progress is not None:
                progress('crbm', epoch, history[-1])
        return history

    def _cd1_gradients(self, v0: torch.Tensor, c: torch.Tensor, gen: torch.Generator
                       ) -> tuple[list[torch.Tensor], float]:
        """CD-1 estimates of the log-likelihood gradients (ascent direction) of a batch."""
        n = v0.shape[0]
        h0 = self.hidden_probs(v0, c)                                  # (S, H)
        h0_sample = torch.bernoulli(h0, generator=gen)
        v1 = self.visible_mean(h0_sample, c)                           # (S, D) mean field
        h1 = self.hidden_probs(v1, c)
        dv, dh = v0 - v1, h0 - h1
        grad_w = (h0.T @ v0 - h1.T @ v1) / n
        grads = [grad_w, dh.T @ c / n, dv.T @ c / n, dv.mean(0), dh.mean(0)]
        return grads, float((dv ** 2).mean())

    # -- transfer -----------------------------------------------------------------------
    def input_layers(self) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
        """Weights and biases for raw (unstandardized) inputs, standardization folded in.

        Returns ``{'visible': (W / v_std, b_h - (W / v_std) v_mean),
        'cond': (B / c_std, -(B / c_std) c_mean)}``, shapes (H, D), (H), (H, C), (H).
        """
        w = self.weight / self.v_std
        bc = self.cond_hidden / self.c_std
        return {'visible': (w.clone(), self.hidden_bias - w @ self.v_mean),
                'cond': (bc.clone(), -(bc @ self.c_mean))}


@torch.no_grad()
def pretrain_input_layers(model: MPRNN, windows: torch.Tensor, cond: torch.Tensor,
                          config: CRBMTrainConfig | None = None,
                          progress: Progress | None = None) -> tuple[CRBM, list[float]]:
    """Stage 1: train a CRBM on (current, past) windows and initialize the cell's inputs.

    Parameters
    ----------
    model
        An :class:`~dlmpc_ros.learning.mprnn.MPRNN`; its ``cell.cur``, ``cell.lcur`` and
        ``cell.past`` layers are overwritten (see the module docstring), nothing else.
    windows
        Current windows ``x_{tau-b+1..tau}``, (S, b, 10) features (or flattened (S, 10 b)).
    cond
        The matching past windows ``x_{tau-2b+1..tau-b}``, same shape.
    config, progress
        CD-1 settings; callback ``progress('crbm', epoch, reconstruction_error)``.

    Returns
    -------
    The trained machine and its per-epoch reconstruction errors.
    """
    config = config or CRBMTrainConfig()
    cell = model.cell
    n_in = cell.cur.in_features
    v, c = _flat(windows), _flat(cond)
    if v.shape[1] != n_in or c.shape[1] != cell.past.in_features:
        raise ValueError(f'windows must hold {n_in} values (b rows of features), got '
                         f'{v.shape[1]} and {c.shape[1]}')
    crbm = CRBM(n_in, c.shape[1], cell.cur.out_features, config.init_std, config.seed)
    history = crbm.fit(v, c, config, progress)
    layers = crbm.input_layers()
    for layer, key in ((cell.cur, 'visible'), (cell.lcur, 'visible'), (cell.past, 'cond')):
        weight, bias = layers[key]
        layer.weight.copy_(weight)
        layer.bias.copy_(bias)
    return crbm, history
