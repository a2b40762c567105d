"""Model-prediction RNN (MP-RNN): predicts N control periods of the laser and of K.

Time indexing (one row per control period). Row ``x_j`` holds the features (see
:mod:`dlmpc_ros.learning.features`) of ``(E_j, M_j)``, measured at the end of period j, and
of ``alpha_j``, the angles applied during period j. The control ``u_{j+1}`` is
``alpha_{j+1}``, and the states are ``v_j = (E_n, logM_n)_j``. A cell at reference step tau
reads

- the past window    ``x_{tau-2b+1 .. tau-b}``   (b rows),
- the current window ``x_{tau-b+1 .. tau}``      (b rows),
- the control window ``u_{tau-b+2 .. tau+1}``    (b rows; the last one is applied next),
- the latent ``l`` of the previous cell,

and predicts ``K_{tau+1}`` (the surrogate birefringence, K head) and ``v_{tau+1}``. The
2N cells of one prediction at current step t sit at ``tau = t-N, ..., t+N-1``: N encoder
cells (tau = t-N .. t-1) whose predictions ``v_{t-N+1..t}`` are one-step predictions of
known rows, then N decoder cells (tau = t .. t+N-1) predicting ``v_{t+1..t+N}``. The first
encoder cell reads back to row ``t-N-2b+1``, so a prediction needs :meth:`MPRNN.min_history`
= N + 2b rows ``x_{t-N-2b+1..t}``, the paper's "N + 2b time steps". (Encoder windows ending
at t-N+1 .. t would need only N + 2b - 1 rows, but then the last encoder cell would predict
the unknown ``v_{t+1}``, duplicating the first decoder cell.)
All cells share one set of weights (one :class:`MPRNNCell`).

Decoder windows reach past t: with ``feed_back=True`` (receding-horizon prediction) row
``x_{t+j}`` is built from the predicted ``v_{t+j}`` and the control ``u_{t+j}`` that was used;
with ``feed_back=False`` (teacher forcing) it is the caller's true ``future_x[:, j-1]``.
The control ``u_{t+j}`` is ``future_u[:, j-1]`` when given, else ``kmap(K_{t+j})``.

Training (no CLI here): :func:`~dlmpc_ros.learning.crbm.pretrain_input_layers` (stage 1,
CRBM), :func:`train_single_step` (stage 2, teacher forcing), :func:`train_receding_horizon`
(stage 3, predictions fed back, BPTT), or all three with :func:`train_three_stage`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from dlmpc_ros.learning.checkpoint import (
    ModelFileError,
    load_checkpoint,
    regenerate_hint,
    save_checkpoint,
)
from dlmpc_ros.learning.crbm import CRBMTrainConfig, Progress, pretrain_input_layers
from dlmpc_ros.learning.features import (
    N_ANGLES,
    N_FEATURES,
    Normalizer,
    angle_features,
    angles_from_features,
    features,
)

N_STATES = 2  # E_n, logM_n
N_ANGLE_FEATURES = 2 * N_ANGLES  # sin 2a, cos 2a

KMap = Callable[[torch.Tensor], torch.Tensor]

__all__ = ['MPRNNConfig', 'MPRNNCell', 'CellOutput', 'MPRNN', 'MPRNNOutput', 'WindowBatch',
           'WindowDataset', 'TrainConfig', 'mprnn_loss', 'pretrain_input_layers',
           'crbm_windows', 'train_single_step', 'train_receding_horizon',
           'train_three_stage', 'HorizonErrors', 'evaluate_horizon_errors', 'save_mprnn',
           'load_mprnn']


#: Bound on the normalized states fed back in a rollout (training data lies within +-5).
FEEDBACK_BOUND = 6.0

@dataclass(frozen=True)
class MPRNNConfig:
    """Everything needed to rebuild an MP-RNN (stored in its model file)."""

    window: int = 5
    """b: rows per input window (the past window is another b rows before it)."""
    horizon: int = 10
    """N: encoder cells and predicted control periods."""
    n_hidden: int = 64
    """N_h: units of every hidden layer (and of the pre-training CRBM)."""
    n_latent: int = 32
    """N_l: size of the recurrent latent l."""
    n_k: int = 1
    """N_K: outputs of the K head (the surrogate's dimension)."""
    residual: bool = False
    """True: predict v_{tau+1} as v_tau plus the output layer (a skip connection that
    starts from persistence). False (default): the appendix's plain output layer, which
    measured better on the held-out trajectories (O error at horizon 10 relative to
    persistence: 0.97 plain, 1.05 residual without the objective term; 0.735 plain, 0.860
    residual with it and the cosine schedule, bench/results/mprnn_variants.md)."""
    norm: dict[str, float] = field(default_factory=lambda: Normalizer().to_dict())
    """Normalizer of E and log M, as :meth:`Normalizer.to_dict`."""

    def __post_init__(self) -> None:
        for name in ('window', 'horizon', 'n_hidden', 'n_latent', 'n_k'):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f'MPRNNConfig.{name} must be an integer >= 1, got {value!r}')
        try:
            Normalizer(**self.norm)
        except TypeError as err:
            raise ValueError(f'MPRNNConfig.norm is not a Normalizer dict: {err}') from None

    @property
    def normalizer(self) -> Normalizer:
        return Normalizer(**self.norm)

    def min_history(self) -> int:
        """Rows of history a prediction needs: N + 2b (see the module docstring)."""
        return self.horizon + 2 * self.window

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MPRNNConfig:
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f'unknown MPRNNConfig keys {sorted(unknown)}')
        return cls(**{k: (dict(v) if k == 'norm' else v) for k, v in data.items()})


@dataclass
class CellOutput:
    """One cell's results (batch B)."""

    v: torch.Tensor  # (B, 2) predicted v_{tau+1}
    k: torch.Tensor  # (B, n_k) predicted K_{tau+1}
    u: torch.Tensor  # (B, 4) control u_{tau+1} used, radians
    latent: torch.Tensor  # (B, N_l) l passed to the next cell


class MPRNNCell(nn.Module):
    """One MP-RNN cell (paper appendix): long-term, current and future-control branches.

    ReLU hidden layers, linear outputs; windows are flattened time-major (row by row).
    """

    def __init__(self, config: MPRNNConfig) -> None:
        super().__init__()
        b, nh, nl = config.window, config.n_hidden, config.n_latent
        n_in = b * N_FEATURES
        self.past = nn.Linear(n_in, nh)        # W_past:  past window -> h_past
        self.lcur = nn.Linear(n_in, nh)        # W_lcur:  current window -> h_lcur
        self.hl = nn.Linear(nh, nl)            # W_hl:    h_past * h_lcur -> l (with b_hl)
        self.ll = nn.Linear(nl, nl, bias=False)  # W_ll:  l_prev -> l
        self.cur = nn.Linear(n_in, nh)         # W_cur:   current window -> h_cur
        self.fut = nn.Linear(b * N_ANGLE_FEATURES, nh)  # W_fut: control window -> h_fut
        self.lat = nn.Linear(nl, nh)           # W_l:     l -> h_lat
        self.ko = nn.Linear(nh, config.n_k)    # W_Ko:    h_lat -> K_{tau+1}
        self.out = nn.Linear(nh, N_STATES)     # W_o:     h_lat * h_cur * h_fut -> v_{tau+1}
        self.residual = config.residual

    def forward(self, x_past: torch.Tensor, x_cur: torch.Tensor, u_known: torch.Tensor,
                latent: torch.Tensor, u_next: torch.Tensor | None = None,
                kmap: KMap | None = None) -> CellOutput:
        """Predict K and v one step past the current window.

        Parameters
        ----------
        x_past, x_cur
            (B, b, 10) past and current feature windows.
        u_known
            (B, b - 1, 8) angle features of ``u_{tau-b+2..tau}`` (the applied controls).
        latent
            (B, N_l) latent of the previous cell (zeros for the first).
        u_next
            (B, 4) control ``u_{tau+1}`` in radians, or None to take ``kmap(K_{tau+1})``.
        kmap
            Map (..., n_k) surrogate -> (..., 4) angles in radians; needed if u_next is None.
        """
        relu = torch.relu
        h_past = relu(self.past(x_past.flatten(1)))                    # (B, N_h)
        h_lcur = relu(self.lcur(x_cur.flatten(1)))                     # (B, N_h)
        latent = relu(self.hl(h_past * h_lcur) + self.ll(latent))      # (B, N_l)
        h_cur = relu(self.cur(x_cur.flatten(1)))                       # (B, N_h)
        h_lat = relu(self.lat(latent))                                 # (B, N_h)
        k = self.ko(h_lat)                                             # (B, n_k)
        if u_next is None:
            if kmap is None:
                raise ValueError('no control given for a predicted step and no K-to-angles '
                                 'map (kmap) to seed it; pass future_u or a kmap')
            u_next = kmap(k)                                           # (B, 4)
        u_window = torch.cat([u_known, angle_features(u_next)[:, None]], dim=1)  # (B, b, 8)
        h_fut = relu(self.fut(u_window.flatten(1)))                    # (B, N_h)
        v = self.out(h_lat * h_cur * h_fut)                            # (B, 2)
        if self.residual:
            v = v + x_cur[:, -1, :N_STATES]                            # skip from v_tau
        return CellOutput(v=v, k=k, u=u_next, latent=latent)


@dataclass
class MPRNNOutput:
    """Predictions of one MP-RNN pass from current step t (batch B, horizon N)."""

    v: torch.Tensor  # (B, N, 2) normalized states v_{t+1..t+N}
    k: torch.Tensor  # (B, N, n_k) surrogate K_{t+1..t+N}
    u: torch.Tensor  # (B, N, 4) controls u_{t+1..t+N} used, radians
    objective: torch.Tensor  # (B, N) O = E / M of v
    v_enc: torch.Tensor  # (B, N, 2) encoder one-step predictions of v_{t-N+1..t}
    k_enc: torch.Tensor  # (B, N, n_k) encoder one-step predictions of K_{t-N+1..t}


class MPRNN(nn.Module):
    """Encoder-decoder of 2N weight-sharing cells (see the module docstring).

    Parameters
    ----------
    config
        Sizes and normalizer.
    kmap
        Optional K-to-angles map used for steps without a given control. It is held by
        reference, not registered as a submodule: its weights are neither in this model's
        ``state_dict`` nor among its ``parameters()``.
    seed
        Seed of the Xavier initialization (all weights; biases zero).
    """

    def __init__(self, config: MPRNNConfig, kmap: KMap | None = None, seed: int = 0) -> None:
        super().__init__()
        self.config = config
        self.norm = config.normalizer
        self.cell = MPRNNCell(config)
        self._kmap = [kmap]  # a list keeps a module out of the registered submodules
        gen = torch.Generator().manual_seed(seed)
        for name, param in self.cell.named_parameters():
            if name.endswith('weight'):
                nn.init.xavier_uniform_(param, generator=gen)
            else:
                nn.init.zeros_(param)

    @property
    def kmap(self) -> KMap | None:
        return self._kmap[0]

    @kmap.setter
    def kmap(self, value: KMap | None) -> None:
        self._kmap[0] = value

    def __setattr__(self, name: str, value) -> None:
        # nn.Module would register a module assigned to `kmap` as a submodule instead of
        # calling the property setter.
        if name == 'kmap':
            self._kmap[0] = value
            return
        super().__setattr__(name, value)

    def min_history(self) -> int:
        """Rows of history :meth:`forward` needs: N + 2b."""
        return self.config.min_history()

    def forward(self, history: torch.Tensor, future_u: torch.Tensor | None = None,
                feed_back: bool = True, future_x: torch.Tensor | None = None) -> MPRNNOutput:
        """Predict the next N control periods from the history ending at step t.

        Parameters
        ----------
        history
            (B, H, 10) features of rows ``..., t``, H >= :meth:`min_history`; only the last
            N + 2b rows are used.
        future_u
            (B, n, 4) controls ``u_{t+1..t+n}`` in radians, 0 <= n <= N, or None; the steps
            past n take ``kmap(K)``. Gradients flow to it.
        feed_back
            True: feed each decoder prediction back as the next rows (``future_x`` is
            ignored). False: teacher forcing with ``future_x``.
        future_x
            (B, N, 10) true features of rows ``t+1..t+N``; required when feed_back is False.
        """
        cfg = self.config
        b, n = cfg.window, cfg.horizon
        need = cfg.min_history()
        if history.ndim != 3 or history.shape[2] != N_FEATURES or history.shape[1] < need:
            raise ValueError(f'history must be (batch, >= {need}, {N_FEATURES}) features, got '
                             f'{tuple(history.shape)}')
        batch = history.shape[0]
        n_given = 0 if future_u is None else future_u.shape[1]
        if future_u is not None and (future_u.ndim != 3 or future_u.shape[0] != batch
                                     or future_u.shape[2] != N_ANGLES or n_given > n):
            raise ValueError(f'future_u must be (batch, <= {n}, {N_ANGLES}) angles, got '
                             f'{tuple(future_u.shape)}')
        if n_given < n and self.kmap is None:
            raise ValueError(f'future_u gives {n_given} of {n} controls and the model has no '
                             'kmap to choose the others; pass all controls or set kmap')
        if not feed_back and (future_x is None or future_x.shape != (batch, n, N_FEATURES)):
            got = None if future_x is None else tuple(future_x.shape)
            raise ValueError(f'feed_back=False needs future_x of shape ({batch}, {n}, '
                             f'{N_FEATURES}), got {got}')

        history = history[:, -need:]                                   # (B, N + 2b, 10)
        rows = list(history.unbind(1))          # rows[i] is x_{t-N-2b+1+i}, each (B, 10)
        controls = [row[:, N_STATES:] for row in rows]  # angle features of u, (B, 8) each
        latent = history.new_zeros(batch, cfg.n_latent)                # (B, N_l)

        def cell_at(i: int, u_next: torch.Tensor | None) -> CellOutput:
            """Cell whose current window ends at rows[i] (tau)."""
            x_past = torch.stack(rows[i - 2 * b + 1:i - b + 1], dim=1)   # (B, b, 10)
            x_cur = torch.stack(rows[i - b + 1:i + 1], dim=1)            # (B, b, 10)
            u_known = history.new_zeros(batch, 0, N_ANGLE_FEATURES)
            if b > 1:
                u_known = torch.stack(controls[i - b + 2:i + 1], dim=1)  # (B, b - 1, 8)
            return self.cell(x_past, x_cur, u_known, latent, u_next, self.kmap)

        v_enc, k_enc = [], []
        for j in range(n):  # encoder: tau = t-N+j, predicts the known v_{t-N+j+1}
            i = 2 * b - 1 + j
            out = cell_at(i, angles_from_features(controls[i + 1]))
            latent = out.latent
            v_enc.append(out.v)
            k_enc.append(out.k)

        v_dec, k_dec, u_dec = [], [], []
        for j in range(n):  # decoder: tau = t+j, predicts v_{t+j+1}
            i = need - 1 + j
            u_next = future_u[:, j] if j < n_given else None
            out = cell_at(i, u_next)
            latent = out.latent
            u_feat = angle_features(out.u)                             # (B, 8)
            if feed_back:
                # Fed back within a bounded range, so that one wild prediction cannot
                # blow up the rest of the rollout (normalized states are O(1)).
                v_back = out.v.clamp(-FEEDBACK_BOUND, FEEDBACK_BOUND)
                rows.append(torch.cat([v_back, u_feat], dim=-1))      # (B, 10) predicted
            else:
                rows.append(future_x[:, j])                            # (B, 10) true
            controls.append(u_feat)
            v_dec.append(out.v)
            k_dec.append(out.k)
            u_dec.append(out.u)

        v = torch.stack(v_dec, dim=1)                                  # (B, N, 2)
        return MPRNNOutput(v=v, k=torch.stack(k_dec, dim=1),           # (B, N, n_k)
                           u=torch.stack(u_dec, dim=1),                # (B, N, 4)
                           objective=self.norm.objective(v),           # (B, N)
                           v_enc=torch.stack(v_enc, dim=1),            # (B, N, 2)
                           k_enc=torch.stack(k_enc, dim=1))            # (B, N, n_k)


# -- data ---------------------------------------------------------------------------------
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


# -- training -----------------------------------------------------------------------------
@dataclass(frozen=True)
class TrainConfig:
    """Settings of the three training stages."""

    crbm: CRBMTrainConfig = field(default_factory=CRBMTrainConfig)
    """Stage 1: CD-1 pre-training of the input layers."""
    single_step_epochs: int = 10
    """Stage 2: epochs of teacher-forced (single-step) training."""
    horizon_epochs: int = 20
    """Stage 3: epochs of receding-horizon training (BPTT over the horizon)."""
    batch_size: int = 64
    """Windows per Adam step."""
    lr: float = 1e-3
    """Adam learning rate (stages 2 and 3)."""
    cosine: bool = False
    """True: the learning rate of each stage decays from ``lr`` to 0 along a half cosine
    over its epochs (per Adam step); False: constant."""
    k_weight: float = 0.1
    """Weight of the K head's squared error against the surrogate."""
    encoder_weight: float = 0.5
    objective_weight: float = 0.0
    """Weight of the squared error of the objective O = E/M (physical units) over the
    horizon; O is what the controller maximizes."""
    """Weight of the encoder cells' one-step errors (v and K)."""
    clip_norm: float = 1.0
    """Gradient-norm clip per step (0: none)."""
    seed: int = 0
    """Seed of the mini-batch order."""

    def __post_init__(self) -> None:
        for name in ('single_step_epochs', 'horizon_epochs'):
            if getattr(self, name) < 0:
                raise ValueError(f'TrainConfig.{name} must be >= 0')
        if self.batch_size < 1 or self.lr <= 0:
            raise ValueError('TrainConfig needs batch_size >= 1 and lr > 0')

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def mprnn_loss(out: MPRNNOutput, batch: WindowBatch, k_weight: float = 0.1,
               encoder_weight: float = 0.5, objective_weight: float = 0.0,
               norm: Normalizer | None = None) -> torch.Tensor:
    """Sum-squared error over the horizon, averaged over the batch.

    ``sum_j |v_{t+j} - v^_{t+j}|^2 + k_weight sum_j (s_{t+j} - K^_{t+j})^2``, plus
    ``encoder_weight`` times the same sums of the encoder's one-step predictions of
    ``v_{t-N+1..t}`` and ``s_{t-N+1..t}``.
    """
    n = out.v.shape[1]
    v_true = batch.future_x[..., :N_STATES]                             # (B, N, 2)
    v_known = batch.history[:, -n:, :N_STATES]                          # (B, N, 2)
    dec = ((out.v - v_true) ** 2).sum((1, 2))
    dec = dec + k_weight * ((out.k[..., 0] - batch.future_s) ** 2).sum(1)
    enc = ((out.v_enc - v_known) ** 2).sum((1, 2))
    enc = enc + k_weight * ((out.k_enc[..., 0] - batch.past_s) ** 2).sum(1)
    total = dec + encoder_weight * enc
    if objective_weight and norm is not None:
        o_true = norm.objective(v_true)                                 # (B, N)
        total = total + objective_weight * ((out.objective - o_true) ** 2).sum(1)
    return total.mean()


def _train_stage(model: MPRNN, data: WindowDataset, config: TrainConfig, epochs: int,
                 feed_back: bool, stage: str, seed_offset: int,
                 progress: Progress | None) -> list[float]:
    if len(data) == 0:
        raise ValueError('no training windows')
    gen = torch.Generator().manual_seed(config.seed + seed_offset)
    opt = torch.optim.Adam(model.parameters(), lr=config.lr)
    steps_per_epoch = -(-len(data) // config.batch_size)
    schedule = (torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * steps_per_epoch)
                if config.cosine and epochs > 0 else None)
    model.train()
    history: list[float] = []
    for epoch in range(epochs):
        order = torch.randperm(len(data), generator=gen)
        total = 0.0
        for start in range(0, len(order), config.batch_size):
            batch = data.batch(order[start:start + config.batch_size])
            out = model(batch.history, batch.future_u, feed_back=feed_back,
                        future_x=batch.future_x)
            loss = mprnn_loss(out, batch, config.k_weight, config.encoder_weight,
                              config.objective_weight, model.norm)
            opt.zero_grad()
            loss.backward()
            if config.clip_norm > 0:
                nn.utils.clip_grad_norm_(model.parameters(), config.clip_norm)
            opt.step()
            if schedule is not None:
                schedule.step()
            total += loss.item() * len(batch)
        history.append(total / len(order))
        if progress is not None:
            progress(stage, epoch, history[-1])
    model.eval()
    return history


def train_single_step(model: MPRNN, data: WindowDataset, config: TrainConfig,
                      progress: Progress | None = None) -> list[float]:
    """Stage 2: teacher forcing (``feed_back=False``), every prediction one step ahead.

    Returns the mean training loss (:func:`mprnn_loss`) of each epoch.
    """
    return _train_stage(model, data, config, config.single_step_epochs, False,
                        'single_step', 1, progress)


def train_receding_horizon(model: MPRNN, data: WindowDataset, config: TrainConfig,
                           progress: Progress | None = None) -> list[float]:
    """Stage 3: predictions fed back (``feed_back=True``), BPTT through the horizon.

    Returns the mean training loss (:func:`mprnn_loss`) of each epoch.
    """
    return _train_stage(model, data, config, config.horizon_epochs, True,
                        'receding_horizon', 2, progress)


def train_three_stage(model: MPRNN, data: WindowDataset, config: TrainConfig,
                      progress: Progress | None = None) -> dict[str, list[float]]:
    """CRBM pre-training, single-step and receding-horizon training, in order.

    Returns per-epoch histories ``{'crbm': reconstruction errors, 'single_step': losses,
    'receding_horizon': losses}``. ``progress(stage, epoch, value)`` after every epoch.
    """
    cur, past = crbm_windows(data)
    _, crbm_history = pretrain_input_layers(model, cur, past, config.crbm, progress)
    return {'crbm': crbm_history,
            'single_step': train_single_step(model, data, config, progress),
            'receding_horizon': train_receding_horizon(model, data, config, progress)}


# -- evaluation ---------------------------------------------------------------------------
@dataclass
class HorizonErrors:
    """RMSE at horizons 1..N in physical units (E: L2 norm, M: kurtosis, O = E / M)."""

    e: np.ndarray  # (N,) model
    m: np.ndarray  # (N,)
    o: np.ndarray  # (N,)
    e_persistence: np.ndarray  # (N,) forecast v_{t+k} = v_t
    m_persistence: np.ndarray  # (N,)
    o_persistence: np.ndarray  # (N,)

    def to_dict(self) -> dict[str, list[float]]:
        """``{'rmse_E_model': [...], 'rmse_E_persistence': [...], ... M, O}`` (horizons 1..N)."""
        out = {}
        for name in ('e', 'm', 'o'):
            for kind, value in (('model', getattr(self, name)),
                                ('persistence', getattr(self, f'{name}_persistence'))):
                out[f'rmse_{name.upper()}_{kind}'] = [float(x) for x in value]
        return out


@torch.no_grad()
def evaluate_horizon_errors(model: MPRNN, windows: WindowDataset,
                            batch_size: int = 512) -> HorizonErrors:
    """Receding-horizon RMSE with the applied controls, against persistence.

    The model predicts with ``feed_back=True`` and ``future_u`` = the applied angles.
    """
    if len(windows) == 0:
        raise ValueError('no windows to evaluate')
    was_training = model.training
    model.eval()
    norm = model.norm
    n = model.config.horizon
    sq = {key: torch.zeros(n, dtype=torch.float64) for key in
          ('e', 'm', 'o', 'e_persistence', 'm_persistence', 'o_persistence')}
    for start in range(0, len(windows), batch_size):
        batch = windows.batch(torch.arange(start, min(start + batch_size, len(windows))))
        out = model(batch.history, batch.future_u)
        e_true, m_true = norm.unstates(batch.future_x[..., :N_STATES])  # (B, N) each
        e_pred, m_pred = norm.unstates(out.v)
        e_now, m_now = norm.unstates(batch.history[:, -1:, :N_STATES])  # (B, 1) each
        for prefix, e, m in (('', e_pred, m_pred), ('persistence', e_now, m_now)):
            suffix = f'_{prefix}' if prefix else ''
            sq['e' + suffix] += ((e - e_true) ** 2).sum(0).double()
            sq['m' + suffix] += ((m - m_true) ** 2).sum(0).double()
            sq['o' + suffix] += ((e / m - e_true / m_true) ** 2).sum(0).double()
    model.train(was_training)
    return HorizonErrors(**{key: (value / len(windows)).sqrt().numpy()
                            for key, value in sq.items()})


# -- model files --------------------------------------------------------------------------
def save_mprnn(path: str | Path, model: MPRNN, metrics: dict[str, Any],
               fingerprint: str) -> Path:
    """Write the model's weights and config (the kmap is not included)."""
    return save_checkpoint(path, 'mprnn', model.state_dict(), model.config.to_dict(),
                           metrics, fingerprint)


def load_mprnn(path: str | Path, kmap: KMap | None = None) -> MPRNN:
    """Rebuild an MP-RNN from its file (in eval mode); raises :class:`ModelFileError`."""
    payload = load_checkpoint(path, 'mprnn')
    try:
        model = MPRNN(MPRNNConfig.from_dict(payload['config']), kmap=kmap)
        model.load_state_dict(payload['state_dict'])
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        raise ModelFileError(f'model file {path} does not hold a valid MP-RNN ({err}); '
                             f'{regenerate_hint("mprnn")}') from None
    return model.eval()
