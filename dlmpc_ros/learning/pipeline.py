"""The training pipeline behind ``dlmpc-train``: estimator, map and predictor stages.

Each stage reads the datasets made by ``dlmpc-data`` and the models of earlier stages,
trains, measures, and writes its model file (with config, metrics and data fingerprint)
and figures into the models directory.
"""

from __future__ import annotations

import itertools
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.learning import shards
from dlmpc_ros.learning.checkpoint import (ModelFileError, fingerprint_arrays, load_checkpoint,
                                          regenerate_hint, save_checkpoint)
from dlmpc_ros.learning.features import Normalizer
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.kmap import KMap, KMapConfig, SubsetRule, train_kmap, training_subset
from dlmpc_ros.learning.oracle import load_envelope
from dlmpc_ros.learning.trajectories import load_trajectories
from dlmpc_ros.learning.vae import (ConditionalVAE, VAEConfig, choose_surrogate,
                                    steady_windows, windows)


@dataclass(frozen=True)
class Paths:
    data_dir: Path = Path('data')
    models_dir: Path = Path('models')

    @property
    def sweep(self) -> Path:
        return self.data_dir / 'sweep'

    @property
    def oracle(self) -> Path:
        return self.data_dir / 'oracle.npz'

    @property
    def trajectories(self) -> Path:
        return self.data_dir / 'trajectories'

    @property
    def extra_trajectories(self) -> Path:
        """More training lanes for the predictor only (see ``dlmpc-data trajectories``)."""
        return self.data_dir / 'trajectories_extra'

    def model(self, kind: str) -> Path:
        return self.models_dir / f'{kind}.pt'

    @property
    def figures(self) -> Path:
        return self.models_dir / 'figures'


def measured_array(data: dict[str, np.ndarray]) -> np.ndarray:
    """Stack E, M and angles into (..., 6) float32 measurements."""
    return np.concatenate([data['E'][..., None], data['M'][..., None], data['alpha']],
                          axis=-1).astype(np.float32)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(np.ravel(a), np.ravel(b))[0, 1])


def _load(path: Path, kind: str, model_cls, config_cls) -> tuple[torch.nn.Module, dict]:
    payload = load_checkpoint(path, kind)
    try:
        model = model_cls(config_cls(**payload['config']))
        model.load_state_dict(payload['state_dict'])
    except (TypeError, RuntimeError, KeyError) as err:
        raise ModelFileError(f'model file {path} does not fit this version\'s {kind} model '
                             f'({type(err).__name__}); {regenerate_hint(kind)}') from None
    model.eval()
    return model, payload


def load_vae(path: Path) -> tuple[ConditionalVAE, dict]:
    """The estimator and its file's payload (config, metrics, fingerprint)."""
    return _load(path, 'vae', ConditionalVAE, VAEConfig)


def load_kmap(path: Path) -> tuple[KMap, dict]:
    """The K-to-angles map and its file's payload."""
    return _load(path, 'kmap', KMap, KMapConfig)


def surrogate_of(vae: ConditionalVAE, measured: np.ndarray) -> np.ndarray:
    """Surrogate (N,) of measurement windows (N, w, 6)."""
    return vae.surrogate(torch.as_tensor(measured, dtype=torch.float32)).numpy()


# -- estimator ------------------------------------------------------------------------------

def train_vae_stage(paths: Paths, seed: int = 0, epochs: int = 25,
                    window_choices: tuple[int, ...] = (1, 4),
                    conditional_choices: tuple[bool, ...] = (True, False),
                    show_progress: bool = True) -> dict:
    """Train one VAE per (decoder kind, window length); keep the one whose surrogate
    tracks K best on the held-out trajectories (K is used for this measurement only, never
    in training), save it and the paper's Fig. 4."""
    started = time.monotonic()
    traj = load_trajectories(paths.trajectories)
    sweep = shards.load_dataset(paths.sweep)
    measured = measured_array(traj)  # (lanes, T, 6)
    train, test = measured[~traj['held_out']], measured[traj['held_out']]
    k_test = traj['K'][traj['held_out']]
    steady = sweep['converged'] & sweep['finite']
    sweep_measured = measured_array(sweep)[steady]
    norm = Normalizer.fit(train[..., 0], train[..., 1])
    fingerprint = fingerprint_arrays({'trajectories': measured, 'sweep': sweep_measured})
    candidates = []
    for conditional, w in itertools.product(conditional_choices, window_choices):
        config = VAEConfig(window=w, conditional=conditional, normalizer=norm.to_dict())
        torch.manual_seed(seed)
        model = ConditionalVAE(config)
        data = np.concatenate([windows(train, w), steady_windows(sweep_measured, w)])
        kind = 'conditional' if conditional else 'plain'
        history = fit(model, model.loss, data, epochs, seed=seed,
                      desc=f'VAE {kind} window {w}', show_progress=show_progress)
        dim, scores = choose_surrogate(model, train)
        with torch.no_grad():
            mu, _ = model.encode(torch.as_tensor(windows(train, w)))
        config.surrogate_dim = dim
        config.surrogate_mean = float(mu[:, dim].mean())
        config.surrogate_std = float(mu[:, dim].std())
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
    save_checkpoint(paths.model('vae'), 'vae', model.state_dict(), model.config.to_dict(),
                    metrics, fingerprint)
    plot_surrogate(model, test, k_test, paths.figures / 'vae_surrogate.png')
    return metrics


def plot_surrogate(model: ConditionalVAE, test: np.ndarray, k_test: np.ndarray,
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


# -- K-to-angles map ---------------------------------------------------------------------------

#: Subset rules tried by the map stage (intervals, delta, top candidates, jump penalty).
#: Candidate subset rules: a weak jump penalty (the targets follow the best O of each
#: interval across branches) and a strong one (one branch-continuous curve). The strong
#: one is what holds lock in closed loop (docs/results/kmap-rules.md); the others are
#: trained and measured for the record.
SHIPPED_RULE = SubsetRule(intervals=21, delta=1.0, top=50, jump_penalty=10.0)
RULE_CHOICES = (SubsetRule(intervals=21, delta=1.0, top=20, jump_penalty=0.1), SHIPPED_RULE,
                SubsetRule(intervals=31, delta=1.0, top=50, jump_penalty=10.0))


def evaluate_map(vae: ConditionalVAE, kmap: KMap, envelope: dict[str, np.ndarray],
                 cavity_cfg: CavityConfig, start_angles: np.ndarray) -> dict[str, np.ndarray]:
    """Steady O at the map's angles, per K of the envelope, from the steady state at
    ``start_angles`` (K points, 4): measure it, estimate the surrogate, apply the map's
    angles, run to steady state again (warm)."""
    k = envelope['K']
    cavity = Cavity(cavity_cfg, batch=k.size, angles=start_angles, birefringence=k)
    first = run_to_steady(cavity, 300, 5)
    measured = np.concatenate([first.E[:, None], first.M[:, None], start_angles],
                              axis=1).astype(np.float32)
    s = surrogate_of(vae, steady_windows(measured, vae.config.window))
    with torch.no_grad():
        angles = kmap(torch.as_tensor(s, dtype=torch.float32)[:, None]).numpy()
    cavity.set_angles(angles.astype(float))
    second = run_to_steady(cavity, 300, 5)
    o_map = np.where(second.finite, np.nan_to_num(second.O), 0.0)
    return {'surrogate': s, 'O_map': o_map, 'ratio': o_map / envelope['O_star'],
            'converged': second.converged, 'angles': angles}


def train_kmap_stage(paths: Paths, seed: int = 0, steps: int = 3000,
                     cavity_cfg: CavityConfig | None = None, show_progress: bool = True) -> dict:
    started = time.monotonic()
    cavity_cfg = cavity_cfg or CavityConfig()
    vae, vae_payload = load_vae(paths.model('vae'))
    sweep = shards.load_dataset(paths.sweep)
    envelope = load_envelope(paths.oracle)
    steady = sweep['converged'] & sweep['finite']
    measured = measured_array(sweep)[steady]
    s = surrogate_of(vae, steady_windows(measured, vae.config.window))
    # Every candidate rule is measured on the even K points of the envelope (validation)
    # by the steady O its map reaches from a typical state (the median-O converged sweep
    # point at each K); the shipped rule was chosen in closed loop, where these one-shot
    # figures did not rank the rules right (docs/results/kmap-rules.md). The figures below
    # quote the odd K points (test) and all.
    val, test = np.arange(0, envelope['K'].size, 2), np.arange(1, envelope['K'].size, 2)
    median_start = np.stack([_median_point(sweep, steady, k) for k in envelope['K']])
    trials = []
    for rule in RULE_CHOICES:
        centres, targets, target_o = training_subset(s, sweep['O'][steady],
                                                     sweep['alpha'][steady], rule)
        model, losses = train_kmap(centres, targets, KMapConfig(), seed=seed, steps=steps)
        at_median = evaluate_map(vae, model, envelope, cavity_cfg, median_start)
        trials.append((float(np.mean(at_median['ratio'][val])), rule, centres, targets,
                       target_o, model, losses, at_median))
    _, rule, centres, targets, target_o, model, losses, at_median = next(
        trial for trial in trials if trial[1] == SHIPPED_RULE)
    at_oracle = evaluate_map(vae, model, envelope, cavity_cfg, envelope['angles'])
    metrics = {
        'subset_rule': rule.__dict__, 'subset_size': int(centres.size),
        'validation_ratio_per_rule': [{'rule': t[1].__dict__,
                                       'validation_ratio_from_median_state': t[0]}
                                      for t in trials],
        'oracle_ratio_test_k': float(np.mean(at_oracle['ratio'][test])),
        'subset_mean_O': float(target_o.mean()), 'final_loss': losses[-1],
        'oracle_ratio_from_oracle_state': float(np.mean(at_oracle['ratio'])),
        'oracle_ratio_from_median_state': float(np.mean(at_median['ratio'])),
        'ratio_of_means_from_oracle_state': float(at_oracle['O_map'].sum()
                                                  / envelope['O_star'].sum()),
        'per_k_ratio_from_oracle_state': at_oracle['ratio'].tolist(),
        'vae_fingerprint': vae_payload['data_fingerprint'],
        'wall_seconds': round(time.monotonic() - started, 1), 'seed': seed,
    }
    save_checkpoint(paths.model('kmap'), 'kmap', model.state_dict(), model.config.to_dict(),
                    metrics, fingerprint_arrays({'centres': centres, 'targets': targets}))
    plot_map(centres, targets, model, envelope, at_oracle, paths.figures / 'kmap.png')
    return metrics


def _median_point(sweep: dict[str, np.ndarray], steady: np.ndarray, k: float) -> np.ndarray:
    rows = np.flatnonzero(steady & (sweep['K'] == k))
    order = rows[np.argsort(sweep['O'][rows])]
    return sweep['alpha'][order[order.size // 2]]


def plot_map(centres, targets, model: KMap, envelope, result, path: Path) -> Path:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (ax_a, ax_o) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    grid = np.linspace(centres.min(), centres.max(), 300)
    with torch.no_grad():
        fit_angles = model(torch.as_tensor(grid, dtype=torch.float32)[:, None]).numpy()
    for i, name in enumerate(('alpha1', 'alpha2', 'alpha3', 'alpha_p')):
        line, = ax_a.plot(grid, fit_angles[:, i], lw=1, label=name)
        ax_a.plot(centres, targets[:, i], '.', color=line.get_color(), ms=4)
    ax_a.set_xlabel('K surrogate (standardized)')
    ax_a.set_ylabel('angle [rad]')
    ax_a.legend(fontsize=8)
    ax_a.set_title('map (lines) and subset-rule targets (dots)')
    ax_o.plot(envelope['K'], envelope['O_star'], label='oracle O*(K)')
    ax_o.plot(envelope['K'], result['O_map'], label='steady O at the map\'s angles')
    ax_o.set_xlabel('true K')
    ax_o.set_ylabel('O')
    ax_o.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_metrics(paths: Paths, stage: str, metrics: dict) -> Path:
    path = paths.models_dir / 'metrics.json'
    existing = json.loads(path.read_text()) if path.exists() else {}
    existing[stage] = metrics
    path.write_text(json.dumps(existing, indent=2, default=float))
    return path
