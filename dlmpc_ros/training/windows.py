"""Training windows of the MP-RNN: every (history, future) cut of a set of trajectories.

Rows are control periods as in :mod:`dlmpc_ros.learning.mprnn`: a window at current step
t holds the history ``x_{t-N-2b+1..t}`` and the future rows ``x_{t+1..t+N}`` with the
angles applied then and the estimator's surrogate (the K head's target).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dlmpc_ros.learning.features import features
from dlmpc_ros.learning.mprnn import MPRNNConfig


@dataclass
class WindowBatch:
    """Training windows at current steps t (batch B)."""

    history: torch.Tensor  # (B, N + 2b, 10) features x_{t-N-2b+1..t}
    future_x: torch.Tensor  # (B, N, 10) true features x_{t+1..t+N}
    future_u: torch.Tensor  # (B, N, 4) applied controls alpha_{t+1..t+N}, radians
    future_s: torch.Tensor  # (B, N) surrogate s_{t+1..t+N} (K head targets)
    past_s: torch.Tensor  # (B, N) surrogate s_{t-N+1..t} (encoder K head targets)

    def __len__(self) -> int:
        return self.history.shape[0]


class WindowDataset:
    """All windows of a set of trajectories, cut lazily per mini-batch.

    Parameters
    ----------
    measured
        (L, T, 6) rows ``(E, M, alpha[4])`` per control period of L trajectories.
    surrogate
        (L, T) the estimator's surrogate birefringence s at each row.
    config
        The model's config (window, horizon and normalizer).
    stride
        Keep every stride-th current step t.
    """

    def __init__(self, measured: np.ndarray, surrogate: np.ndarray, config: MPRNNConfig,
                 stride: int = 1) -> None:
        measured = np.asarray(measured, dtype=np.float64)
        surrogate = np.asarray(surrogate, dtype=np.float64)
        if measured.ndim != 3 or measured.shape[2] != 6:
            raise ValueError(f'measured must be (trajectories, T, 6), got {measured.shape}')
        if surrogate.shape != measured.shape[:2]:
            raise ValueError(f'surrogate must be (trajectories, T) = {measured.shape[:2]}, '
                             f'got {surrogate.shape}')
        if stride < 1:
            raise ValueError('stride must be >= 1')
        self.config = config
        self.history_len = config.min_history()
        n, span = config.horizon, config.min_history() + config.horizon
        n_traj, n_t = measured.shape[:2]
        if n_t < span:
            raise ValueError(f'trajectories of {n_t} rows are shorter than one window '
                             f'(N + 2b + N = {span})')
        meas = torch.as_tensor(measured)
        self.feats = features(meas, config.normalizer).float()          # (L, T, 10)
        self.angles = meas[..., 2:6].float()                            # (L, T, 4)
        self.surrogate = torch.as_tensor(surrogate).float()             # (L, T)
        steps = torch.arange(self.history_len - 1, n_t - n, stride)     # current steps t
        traj = torch.arange(n_traj).repeat_interleave(len(steps))
        self.index = torch.stack([traj, steps.repeat(n_traj)], dim=1)   # (S, 2)

    def __len__(self) -> int:
        return self.index.shape[0]

    def subset(self, keep: torch.Tensor | np.ndarray) -> WindowDataset:
        """A view with the windows ``keep`` (indices or a boolean mask)."""
        other = object.__new__(WindowDataset)
        other.__dict__.update(self.__dict__)
        other.index = self.index[torch.as_tensor(keep)]
        return other

    def batch(self, idx: torch.Tensor | None = None) -> WindowBatch:
        """Windows ``idx`` (all if None) as tensors."""
        index = self.index if idx is None else self.index[idx]
        traj, t = index[:, 0:1], index[:, 1:2]
        n, h = self.config.horizon, self.history_len
        past = t + torch.arange(-h + 1, 1)                              # (B, N + 2b)
        fut = t + torch.arange(1, n + 1)                                # (B, N)
        return WindowBatch(history=self.feats[traj, past], future_x=self.feats[traj, fut],
                           future_u=self.angles[traj, fut], future_s=self.surrogate[traj, fut],
                           past_s=self.surrogate[traj, past[:, -n:]])


def crbm_windows(data: WindowDataset) -> tuple[torch.Tensor, torch.Tensor]:
    """(current, past) windows (S, b, 10) of every reference step of the trajectories.

    For each tau >= 2b - 1: current ``x_{tau-b+1..tau}`` and past ``x_{tau-2b+1..tau-b}``.
    """
    b = data.config.window
    n_t = data.feats.shape[1]
    tau = torch.arange(2 * b - 1, n_t)
    cur = tau[:, None] + torch.arange(-b + 1, 1)                        # (S', b)
    cur_w = data.feats[:, cur].flatten(0, 1)                            # (S, b, 10)
    past_w = data.feats[:, cur - b].flatten(0, 1)                       # (S, b, 10)
    return cur_w, past_w
