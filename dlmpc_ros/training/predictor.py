"""Training of the MP-RNN (paper appendix), in three stages, and its horizon errors.

1. :func:`~dlmpc_ros.training.crbm.pretrain_input_layers`: a conditional RBM trained by
   CD-1 initializes the cell's input layers;
2. :func:`train_single_step`: teacher forcing, every prediction one step ahead;
3. :func:`train_receding_horizon`: predictions fed back, backpropagation through the
   horizon.

:func:`train_three_stage` runs all three; :func:`evaluate_horizon_errors` measures the
receding-horizon RMSE against persistence. Every stage is the shared loop
:func:`~dlmpc_ros.learning.fit.fit`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from dlmpc_ros.core import checks
from dlmpc_ros.learning.features import Normalizer
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.mprnn import N_STATES, MPRNN, MPRNNOutput
from dlmpc_ros.training.crbm import CRBMTrainConfig, Progress, pretrain_input_layers
from dlmpc_ros.training.windows import WindowBatch, WindowDataset, crbm_windows


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
    """Weight of the encoder cells' one-step errors (v and K)."""
    objective_weight: float = 0.0
    """Weight of the squared error of the objective O = E/M (physical units) over the
    horizon; O is what the controller maximizes."""
    clip_norm: float = 1.0
    """Gradient-norm clip per step (0: none)."""
    seed: int = 0
    """Seed of the mini-batch order."""

    def __post_init__(self) -> None:
        checks.counts(self, 'single_step_epochs', 'horizon_epochs', 'seed', minimum=0)
        checks.counts(self, 'batch_size')
        checks.positive(self, 'lr')
        checks.non_negative(self, 'k_weight', 'encoder_weight', 'objective_weight',
                            'clip_norm')

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

    def loss(batch: WindowBatch, _generator: torch.Generator) -> tuple[torch.Tensor, dict]:
        out = model(batch.history, batch.future_u, feed_back=feed_back,
                    future_x=batch.future_x)
        return mprnn_loss(out, batch, config.k_weight, config.encoder_weight,
                          config.objective_weight, model.norm), {}

    def on_epoch(epoch: int, value: float) -> None:
        if progress is not None:
            progress(stage, epoch, value)

    return fit(model, loss, data, epochs, batch=config.batch_size, lr=config.lr,
               seed=config.seed + seed_offset, cosine=config.cosine,
               clip_norm=config.clip_norm, on_epoch=on_epoch, show_progress=False)


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


# -- measurement ------------------------------------------------------------------------
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
