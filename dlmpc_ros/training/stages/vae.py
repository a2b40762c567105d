"""``dlmpc-train vae``: the unsupervised birefringence estimator and its K surrogate.

One VAE is trained per (decoder kind, window length) on the training trajectories and the
sweep's steady states; in each, the K surrogate is the smoothest used latent coordinate
over time (:func:`choose_surrogate`, no labels). The model whose surrogate tracks K best
on the held-out trajectories is kept (K is used for this measurement only, never in
training), with the paper's Fig. 4.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros.core.fingerprint import fingerprint_arrays
from dlmpc_ros.learning.checkpoint import save_checkpoint
from dlmpc_ros.learning.features import Normalizer, measurements
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.vae import (ConditionalVAE, VAEConfig, export_encoder, steady_windows,
                                    surrogate_of, windows)
from dlmpc_ros.training import shards
from dlmpc_ros.training.trajectories import load_trajectories
from dlmpc_ros.training.workspace import Workspace


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(np.ravel(a), np.ravel(b))[0, 1])


def smoothest_used(kl: np.ndarray, differences: np.ndarray, variance: np.ndarray,
                   min_kl: float = 0.05) -> tuple[int, np.ndarray]:
    """The label-free choice of the surrogate coordinate: of the used latent coordinates
    (mean KL (latent,) above ``min_kl``; all if none is), the one whose changes between
    consecutive windows ``differences`` (n, latent) are smallest against its ``variance``
    (latent,). Returns it and every coordinate's roughness (latent,)."""
    roughness = (differences ** 2).mean(axis=0) / variance
    eligible = np.flatnonzero(kl > min_kl)
    if eligible.size == 0:
        eligible = np.arange(kl.size)
    return int(eligible[np.argmin(roughness[eligible])]), roughness


def label_free_choice(mu: np.ndarray, logvar: np.ndarray, following: np.ndarray,
                      min_kl: float = 0.05) -> tuple[int, dict[str, list[float]]]:
    """:func:`smoothest_used` from the posterior means and log-variances (n, latent) of
    windows in time order; ``following`` (n - 1,) is True where window i + 1 comes one
    step after window i (the changes between those are the roughness). Returns the
    coordinate and the per-coordinate scores."""
    kl = (-0.5 * (1 + logvar - mu ** 2 - np.exp(logvar))).mean(axis=0)
    dim, roughness = smoothest_used(kl, np.diff(mu, axis=0)[following], mu.var(axis=0),
                                    min_kl)
    return dim, {'kl_per_dim': kl.tolist(), 'roughness_per_dim': roughness.tolist()}


def choose_surrogate(model: ConditionalVAE, trajectories: np.ndarray,
                     min_kl: float = 0.05) -> tuple[int, dict[str, list[float]]]:
    """Pick the smoothest used latent coordinate over time (no K labels).

    trajectories: (lanes, T, 6). Returns the coordinate and the per-coordinate scores.
    """
    w = model.config.window
    with torch.no_grad():
        batch = torch.as_tensor(windows(trajectories, w), dtype=torch.float32)
        mu, logvar = model.encode(batch)
    steps = trajectories.shape[1] - w + 1
    following = np.arange(1, mu.shape[0]) % steps != 0  # not across a lane's end
    return label_free_choice(mu.numpy(), logvar.numpy(), following, min_kl)


def train_vae_stage(ws: Workspace, seed: int = 0, epochs: int = 25,
                    window_choices: tuple[int, ...] = (1, 4),
                    conditional_choices: tuple[bool, ...] = (True, False),
                    show_progress: bool = True) -> dict:
    """Train the candidates, keep the best, save it and its figure; returns the metrics."""
    started = time.monotonic()
    traj = load_trajectories(ws.trajectories)
    sweep = shards.load_dataset(ws.sweep)
    measured = measurements(traj)  # (lanes, T, 6)
    train, test = measured[~traj['held_out']], measured[traj['held_out']]
    k_test = traj['K'][traj['held_out']]
    steady = sweep['converged'] & sweep['finite']
    sweep_measured = measurements(sweep)[steady]
    norm = Normalizer.fit(train[..., 0], train[..., 1])
    fingerprint = fingerprint_arrays({'trajectories': measured, 'sweep': sweep_measured})
    candidates = []
    for conditional, w in itertools.product(conditional_choices, window_choices):
        config = VAEConfig(window=w, conditional=conditional, normalizer=norm.to_dict())
        model = ConditionalVAE(config, generator=torch.Generator().manual_seed(seed))
        data = np.concatenate([windows(train, w), steady_windows(sweep_measured, w)])
        kind = 'conditional' if conditional else 'plain'
        history = fit(model, model.loss, data, epochs, seed=seed,
                      desc=f'VAE {kind} window {w}', show_progress=show_progress)
        dim, scores = choose_surrogate(model, train)
        with torch.no_grad():
            mu, _ = model.encode(torch.as_tensor(windows(train, w)))
        model.config = replace(config, surrogate_dim=dim,
                               surrogate_mean=float(mu[:, dim].mean()),
                               surrogate_std=float(mu[:, dim].std()))
        s_test = surrogate_of(model, windows(test, w)).reshape(test.shape[0], -1)
        k_aligned = k_test[:, w - 1:]
        per_lane = [abs(pearson(s, k)) for s, k in zip(s_test, k_aligned)]
        candidates.append({
            'model': model, 'window': w, 'conditional': conditional, 'loss_history': history,
            'surrogate_dim': dim,
            'abs_pearson_r_heldout': abs(pearson(s_test, k_aligned)),
            'abs_pearson_r_per_trajectory_min': float(min(per_lane)),
            'abs_pearson_r_per_trajectory_median': float(np.median(per_lane)), **scores})
    best = max(candidates, key=lambda c: c['abs_pearson_r_heldout'])
    metrics = {
        'chosen_window': best['window'], 'chosen_conditional': best['conditional'],
        'abs_pearson_r_heldout': best['abs_pearson_r_heldout'],
        'candidates': [{k: v for k, v in c.items() if k != 'model'} for c in candidates],
        'train_samples': int(windows(train, best['window']).shape[0]
                             + sweep_measured.shape[0]),
        'wall_seconds': round(time.monotonic() - started, 1), 'seed': seed,
    }
    model = best['model']
    save_checkpoint(ws.model('vae'), 'vae', model.state_dict(), model.config.to_dict(),
                    metrics, fingerprint)
    export_encoder(model, ws.models_dir, {'made_by': 'dlmpc-train vae', 'of': 'vae.pt',
                                          'data_fingerprint': fingerprint})
    plot_latents(model, test, k_test, ws.figures / 'vae_surrogate.png')
    return metrics


def plot_latents(model: ConditionalVAE, test: np.ndarray, k_test: np.ndarray,
                 path: Path, lane: int = 0) -> Path:
    """The paper's Fig. 4: true K and each latent coordinate over one held-out trajectory."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    w = model.config.window
    with torch.no_grad():
        mu, _ = model.encode(torch.as_tensor(windows(test[lane:lane + 1], w)))
    k = k_test[lane, w - 1:]
    fig, axes = plt.subplots(mu.shape[1] + 1, 1, figsize=(9, 2.2 * (mu.shape[1] + 1)),
                             sharex=True, constrained_layout=True)
    steps = np.arange(k.size) + w - 1
    axes[0].plot(steps, k, color='tab:blue')
    axes[0].set_ylabel('true K')
    for d in range(mu.shape[1]):
        z = mu[:, d].numpy()
        z = (z - z.mean()) / (z.std() + 1e-12)
        r = pearson(z, k)
        scaled = np.sign(r) * z * k.std() + k.mean()  # sign and scale for display only
        axes[d + 1].plot(steps, k, color='tab:blue', lw=0.8, alpha=0.5, label='true K')
        chosen = ' (K surrogate)' if d == model.config.surrogate_dim else ''
        axes[d + 1].plot(steps, scaled, color='tab:green' if chosen else 'tab:gray', lw=0.8,
                         label=f'latent {d}{chosen}, |r| = {abs(r):.3f}')
        axes[d + 1].legend(loc='upper right', fontsize=8)
        axes[d + 1].set_ylabel(f'latent {d}')
    axes[-1].set_xlabel('control period (10 round trips)')
    fig.suptitle('VAE latent coordinates against the true birefringence (held-out trajectory)')
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
