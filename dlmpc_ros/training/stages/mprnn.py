"""``dlmpc-train mprnn``: the MP-RNN predictor on the trajectories, its horizon errors.

The rows are the measurements of the trajectories with the VAE's surrogate (the K head's
target). Training lanes: those of ``data/trajectories`` plus every lane of
``data/trajectories_extra``; the held-out lanes of ``data/trajectories`` are split in two
(:func:`split_held_out`): the first half chooses between the models after stage 2 and
after stage 3 (lower O error at horizon N), the second half measures.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dlmpc_ros.core.fingerprint import fingerprint_arrays
from dlmpc_ros.learning.features import measurements
from dlmpc_ros.learning.kmap import load_kmap
from dlmpc_ros.learning.mprnn import MPRNN, MPRNNConfig, AngleMap, save_mprnn
from dlmpc_ros.learning.vae import ConditionalVAE, load_vae, surrogate_of, windows
from dlmpc_ros.training.crbm import CRBMTrainConfig
from dlmpc_ros.training.predictor import TrainConfig, evaluate_horizon_errors, train_three_stage
from dlmpc_ros.training.trajectories import load_trajectories
from dlmpc_ros.training.windows import WindowDataset
from dlmpc_ros.training.workspace import Workspace

#: The shipped training (bench/results/mprnn_variants.md: the cosine decay helped, a higher
#: rate, more epochs, wider layers and the residual output did not; more training lanes did).
FULL = TrainConfig(crbm=CRBMTrainConfig(epochs=5), single_step_epochs=10, horizon_epochs=20,
                   batch_size=256, lr=1e-3, objective_weight=400.0, cosine=True)
QUICK = TrainConfig(crbm=CRBMTrainConfig(epochs=1, max_samples=2000), single_step_epochs=1,
                    horizon_epochs=1, batch_size=64)


def surrogate_series(vae: ConditionalVAE, measured: np.ndarray) -> np.ndarray:
    """Surrogate (lanes, T) of trajectories (lanes, T, 6); the first w-1 rows repeat the
    first full window's value."""
    w = vae.config.window
    s = surrogate_of(vae, windows(measured, w)).reshape(measured.shape[0], -1)
    return np.concatenate([np.repeat(s[:, :1], w - 1, axis=1), s], axis=1)


def split_held_out(held_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validation and test lane indices of the held-out lanes ((lanes,) booleans): the
    first half chooses between models, the second half measures (the same lanes when
    there is only one)."""
    held = np.flatnonzero(held_out)
    val_lanes, test_lanes = held[:max(1, held.size // 2)], held[max(1, held.size // 2):]
    return val_lanes, (test_lanes if test_lanes.size else val_lanes)


@dataclass(frozen=True)
class PredictorData:
    """The rows the predictor trains and is measured on."""

    measured: np.ndarray
    """(lanes, T, 6) measurements of ``data/trajectories`` (all lanes)."""
    surrogate: np.ndarray
    """(lanes, T) the VAE's surrogate of those rows."""
    train_measured: np.ndarray
    """(train lanes, T, 6) every training lane (those of the extra directories too)."""
    train_surrogate: np.ndarray
    """(train lanes, T) their surrogate."""
    val_lanes: np.ndarray
    """Lanes of ``measured`` that choose between models."""
    test_lanes: np.ndarray
    """Lanes of ``measured`` that measure."""

    def fingerprint(self) -> str:
        return fingerprint_arrays({'measured': self.measured, 'surrogate': self.surrogate,
                                   'train_measured': self.train_measured})


def predictor_data(ws: Workspace, vae: ConditionalVAE,
                   extra_trajectories: tuple[Path, ...] = ()) -> PredictorData:
    """The rows of ``ws.trajectories`` and the training lanes of ``extra_trajectories``."""
    traj = load_trajectories(ws.trajectories)
    measured = measurements(traj)
    surrogate = surrogate_series(vae, measured)
    train_measured = [measured[~traj['held_out']]]
    train_surrogate = [surrogate[~traj['held_out']]]
    for directory in extra_trajectories:
        extra = load_trajectories(Path(directory))
        train_measured.append(measurements(extra)[~extra['held_out']])
        train_surrogate.append(surrogate_series(vae, train_measured[-1]))
    val_lanes, test_lanes = split_held_out(traj['held_out'])
    return PredictorData(measured, surrogate, np.concatenate(train_measured),
                         np.concatenate(train_surrogate), val_lanes, test_lanes)


def train_predictor(data: PredictorData, kmap: AngleMap, config: MPRNNConfig,
                    train_cfg: TrainConfig, seed: int = 0, stride: int = 1,
                    show_progress: bool = True) -> tuple[MPRNN, dict]:
    """Train an MP-RNN of ``config`` with ``train_cfg``; returns it (the better of the
    models after stages 2 and 3 on the validation lanes) and its metrics (test and
    validation horizon errors, histories, settings)."""
    started = time.monotonic()
    train = WindowDataset(data.train_measured, data.train_surrogate, config, stride=stride)
    val = WindowDataset(data.measured[data.val_lanes], data.surrogate[data.val_lanes], config,
                        stride=5)
    test = WindowDataset(data.measured[data.test_lanes], data.surrogate[data.test_lanes],
                         config, stride=1)
    model = MPRNN(config, kmap=kmap, seed=seed)
    total = train_cfg.crbm.epochs + train_cfg.single_step_epochs + train_cfg.horizon_epochs
    bar = tqdm(total=total, desc='MP-RNN', unit='epoch', disable=not show_progress)
    snapshots: dict[str, tuple[dict, float]] = {}

    def progress(stage: str, epoch: int, value: float) -> None:
        bar.update(1)
        bar.set_postfix(stage=stage, value=f'{value:.4f}')
        last_epoch = {'single_step': train_cfg.single_step_epochs - 1,
                      'receding_horizon': train_cfg.horizon_epochs - 1}.get(stage)
        if epoch == last_epoch:
            err = evaluate_horizon_errors(model, val)
            snapshots[stage] = (copy.deepcopy(model.state_dict()), float(err.o[-1]))
            model.train()

    histories = train_three_stage(model, train, train_cfg, progress)
    bar.close()
    chosen = min(snapshots, key=lambda k: snapshots[k][1]) if snapshots else 'receding_horizon'
    if snapshots:
        model.load_state_dict(snapshots[chosen][0])
    model.eval()
    errors = evaluate_horizon_errors(model, test).to_dict()
    val_errors = evaluate_horizon_errors(model, val)
    metrics = {
        **{k: [float(x) for x in v] for k, v in errors.items()},
        'validation_rmse_O_model': [float(x) for x in val_errors.o],
        'validation_rmse_O_persistence': [float(x) for x in val_errors.o_persistence],
        'model_config': {k: v for k, v in config.to_dict().items() if k != 'norm'},
        'chosen_after_stage': chosen,
        'validation_O_rmse_at_horizon': {k: v[1] for k, v in snapshots.items()},
        'histories': histories, 'train_windows': len(train), 'test_windows': len(test),
        'train_trajectories': int(data.train_measured.shape[0]),
        'train_config': train_cfg.to_dict(),
        'wall_seconds': round(time.monotonic() - started, 1), 'seed': seed,
    }
    return model, metrics


def train_mprnn_stage(ws: Workspace, seed: int = 0, quick: bool = False,
                      show_progress: bool = True) -> dict:
    """Train the shipped predictor (:data:`FULL`, or :data:`QUICK` for tests) on the
    trajectories and the extra training lanes; save it and its figure; returns the
    metrics."""
    started = time.monotonic()
    vae, vae_payload = load_vae(ws.model('vae'))
    kmap, _ = load_kmap(ws.model('kmap'))
    data = predictor_data(ws, vae, (ws.extra_trajectories,))
    train_cfg = QUICK if quick else TrainConfig(**{**FULL.__dict__, 'seed': seed})
    config = MPRNNConfig(norm=vae.config.normalizer)
    model, metrics = train_predictor(data, kmap, config, train_cfg, seed,
                                     show_progress=show_progress)
    metrics.update({'vae_fingerprint': vae_payload['data_fingerprint'],
                    'wall_seconds': round(time.monotonic() - started, 1)})
    save_mprnn(ws.model('mprnn'), model, metrics, data.fingerprint())
    plot_horizon_errors(metrics, ws.figures / 'mprnn_horizon.png')
    return metrics


def plot_horizon_errors(metrics: dict, path: Path) -> Path:
    """RMSE of E, M and O over the horizon, the model against persistence."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.5), constrained_layout=True)
    for ax, key in zip(axes, ('E', 'M', 'O')):
        model = metrics[f'rmse_{key}_model']
        steps = np.arange(1, len(model) + 1)
        ax.plot(steps, model, 'o-', label='MP-RNN')
        ax.plot(steps, metrics[f'rmse_{key}_persistence'], 's--', label='persistence')
        ax.set_xlabel('horizon (control periods)')
        ax.set_ylabel(f'RMSE of {key}')
        ax.legend(fontsize=8)
    fig.suptitle('Prediction error on held-out trajectories')
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
