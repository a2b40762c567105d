"""The predictor stage of ``dlmpc-train``: windows, three-stage training, horizon errors."""

from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from dlmpc_ros.learning.checkpoint import fingerprint_arrays
from dlmpc_ros.learning.crbm import CRBMTrainConfig
from dlmpc_ros.learning.mprnn import (MPRNN, MPRNNConfig, TrainConfig, WindowDataset,
                                      evaluate_horizon_errors, save_mprnn, train_three_stage)
from dlmpc_ros.learning.pipeline import (Paths, load_kmap, load_vae, measured_array,
                                         surrogate_of)
from dlmpc_ros.learning.trajectories import load_trajectories
from dlmpc_ros.learning.vae import windows

#: The shipped training (bench/results/mprnn_variants.md: the cosine decay helped, a higher
#: rate, more epochs, wider layers and the residual output did not; more training lanes did).
FULL = TrainConfig(crbm=CRBMTrainConfig(epochs=5), single_step_epochs=10, horizon_epochs=20,
                   batch_size=256, lr=1e-3, objective_weight=400.0, cosine=True)
QUICK = TrainConfig(crbm=CRBMTrainConfig(epochs=1, max_samples=2000), single_step_epochs=1,
                    horizon_epochs=1, batch_size=64)


def surrogate_series(vae, measured: np.ndarray) -> np.ndarray:
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


def train_mprnn_stage(paths: Paths, seed: int = 0, quick: bool = False,
                      show_progress: bool = True, stride: int = 1,
                      model_overrides: dict | None = None,
                      train_overrides: dict | None = None, save: bool = True,
                      extra_trajectories: tuple[Path, ...] = ()) -> dict:
    """Train the MP-RNN on the training trajectories; measure on held-out ones.

    Held-out lanes are split in two: the first half chooses between the models after
    stage 2 and after stage 3 (lower O error at horizon N), the second half measures.
    ``model_overrides`` and ``train_overrides`` replace fields of :class:`MPRNNConfig` and
    of the stage's :class:`TrainConfig` (for ablations, bench/mprnn_variants.py); with
    ``save=False`` nothing is written. The metrics include the validation errors
    (``validation_rmse_O_*``) beside the test ones. The training lanes of every
    ``extra_trajectories`` directory join the training set (validation and test stay the
    held-out lanes of ``paths.trajectories``).
    """
    started = time.monotonic()
    traj = load_trajectories(paths.trajectories)
    vae, vae_payload = load_vae(paths.model('vae'))
    kmap, _ = load_kmap(paths.model('kmap'))
    measured = measured_array(traj)
    surrogate = surrogate_series(vae, measured)
    val_lanes, test_lanes = split_held_out(traj['held_out'])
    config = MPRNNConfig(**{'norm': vae.config.normalizer, **(model_overrides or {})})
    train_cfg = QUICK if quick else TrainConfig(**{**FULL.__dict__, 'seed': seed})
    if train_overrides:
        train_cfg = TrainConfig(**{**train_cfg.__dict__, **train_overrides})
    train_measured = [measured[~traj['held_out']]]
    train_surrogate = [surrogate[~traj['held_out']]]
    for directory in extra_trajectories:
        extra = load_trajectories(Path(directory))
        train_measured.append(measured_array(extra)[~extra['held_out']])
        train_surrogate.append(surrogate_series(vae, train_measured[-1]))
    train_measured = np.concatenate(train_measured)
    train = WindowDataset(train_measured, np.concatenate(train_surrogate), config,
                          stride=stride)
    val = WindowDataset(measured[val_lanes], surrogate[val_lanes], config, stride=5)
    test = WindowDataset(measured[test_lanes], surrogate[test_lanes], config, stride=1)
    torch.manual_seed(seed)
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
        'train_trajectories': int(train_measured.shape[0]),
        'train_config': train_cfg.to_dict(), 'vae_fingerprint': vae_payload['data_fingerprint'],
        'wall_seconds': round(time.monotonic() - started, 1), 'seed': seed,
    }
    if save:
        save_mprnn(paths.model('mprnn'), model, metrics,
                   fingerprint_arrays({'measured': measured, 'surrogate': surrogate,
                                       'train_measured': train_measured}))
        plot_horizon_errors(metrics, paths.figures / 'mprnn_horizon.png')
    return metrics


def plot_horizon_errors(metrics: dict, path) -> None:
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
