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

Training (CRBM pre-training, teacher forcing, then predictions fed back) is
:mod:`dlmpc_ros.training.predictor`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import torch
from torch import nn

from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import load_model, save_checkpoint
from dlmpc_ros.learning.features import (
    N_ANGLES,
    N_FEATURES,
    Normalizer,
    angle_features,
    angles_from_features,
)

N_STATES = 2  # E_n, logM_n
N_ANGLE_FEATURES = 2 * N_ANGLES  # sin 2a, cos 2a

#: A K-to-angles map: surrogate (..., n_k) -> angles (..., 4) [rad], e.g. a trained KMap.
AngleMap = Callable[[torch.Tensor], torch.Tensor]
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
        checks.counts(self, 'window', 'horizon', 'n_hidden', 'n_latent', 'n_k')
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
                kmap: AngleMap | None = None) -> CellOutput:
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

    def __init__(self, config: MPRNNConfig, kmap: AngleMap | None = None, seed: int = 0) -> None:
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
    def kmap(self) -> AngleMap | None:
        return self._kmap[0]

    @kmap.setter
    def kmap(self, value: AngleMap | None) -> None:
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


# -- model files --------------------------------------------------------------------------
def save_mprnn(path: str | Path, model: MPRNN, metrics: dict[str, Any],
               fingerprint: str) -> Path:
    """Write the model's weights and config (the kmap is not included)."""
    return save_checkpoint(path, 'mprnn', model.state_dict(), model.config.to_dict(),
                           metrics, fingerprint)


def load_mprnn(path: str | Path, kmap: AngleMap | None = None) -> MPRNN:
    """Rebuild an MP-RNN from its file (in eval mode); raises
    :class:`~dlmpc_ros.learning.checkpoint.ModelFileError`."""
    model, _ = load_model(path, 'mprnn',
                          lambda config: MPRNN(MPRNNConfig.from_dict(config), kmap=kmap))
    return model
