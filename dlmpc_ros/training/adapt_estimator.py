"""The estimator part of ``dlmpc-train adapt``: the paper's VAE and K-to-angles map,
learned on the lab's laser from its bag.

The shipped estimator was trained on the nominal cavity's trajectories and reads one
measurement at a time; on another laser its surrogate hardly follows K (|r| 0.05 and 0.08
on the later quarter of exploring bags of development plants 1 and 5). A window of
measurements under the tracker's dither tells K on the laser the window model was learned
on (``bench/results/window_estimator.md``). From the bag's control periods (E and M the
mean of each period's round trips, as the controller forms them, and the angles) this
module

1. cuts every window of ``window`` consecutive periods that all hold a pulse;
2. trains the conditional VAE (:class:`~dlmpc_ros.learning.vae.ConditionalVAE`) on the
   windows of the run's first ``1 - validation`` share, without labels, and picks its
   surrogate coordinate as ``dlmpc-train vae`` does (the smoothest used one,
   :func:`~dlmpc_ros.training.stages.vae.smoothest_used`), standardized over those windows;
3. fits the K-to-angles map from that surrogate with the paper's subset rule
   (:func:`~dlmpc_ros.training.stages.kmap.training_subset`) over the laser's own states:
   for each interval of the surrogate, the angles at which this laser showed the highest O.

No K and no plant parameter is read: the bag's ``/laser/state`` only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import PeriodMeasurement
from dlmpc_ros.core import checks
from dlmpc_ros.core.fingerprint import fingerprint_arrays
from dlmpc_ros.learning.checkpoint import save_checkpoint
from dlmpc_ros.learning.features import Normalizer
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.kmap import KMap, KMapConfig, load_kmap
from dlmpc_ros.learning.vae import ConditionalVAE, VAEConfig, export_encoder, surrogate_of
from dlmpc_ros.training.stages.kmap import SHIPPED_RULE, SubsetRule, train_kmap, training_subset
from dlmpc_ros.training.stages.vae import label_free_choice


@dataclass(frozen=True)
class EstimatorAdaptConfig:
    """Settings of the estimator's calibration (times in control periods)."""

    window: int = 12
    """Periods per estimator window (two dither cycles of the tracker)."""
    latent: int = 3
    beta: float = 0.05
    """Weight of the KL term (that of ``bench/window_estimator.py``)."""
    epochs: int = 60
    min_windows: int = 200
    """Fewest training windows worth a laser's own estimator (fewer: the shipped one)."""
    rule: SubsetRule = SHIPPED_RULE
    """The map's subset rule (the shipped map's)."""
    map_steps: int = 3000
    """Adam steps of the map's fit."""

    def __post_init__(self) -> None:
        checks.counts(self, 'window', 'latent', 'epochs', 'min_windows', 'map_steps')
        checks.positive(self, 'beta')


def period_rows(states: np.ndarray, period: int, round_trips: int) -> np.ndarray:
    """The control periods' measurements (P, 6) ``(E, M, alpha[4])`` of ``/laser/state``
    messages (n, 10) in the recorded order: the mean E and M of each period's last
    ``round_trips`` round trips at its angles (:class:`PeriodMeasurement` without the
    commands: every period, as with servos that reach a command at once)."""
    states = np.asarray(states, float)
    states = states[np.isfinite(states).all(axis=1)]
    states = states[np.argsort(states[:, 0], kind='stable')]
    periods = PeriodMeasurement(period, round_trips)
    rows = []
    for state in states:
        r = int(state[0])
        if periods.wanted(r):
            row = periods.add(r, itf.measured_state(state))
            if row is not None:
                rows.append(row)
                periods.command(None)  # the bag's commands are not read
    return np.asarray(rows, float).reshape(-1, 6)


def pulse_windows(rows: np.ndarray, window: int, pulse_fraction: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Every window (B, w, 6) of ``window`` consecutive periods that all hold a pulse (O
    at least ``pulse_fraction`` of the run's best), in time order, and the index (B,) of
    the period each ends at."""
    objective = rows[:, 0] / rows[:, 1]
    pulse = np.isfinite(objective) & (objective >= pulse_fraction * np.nanmax(objective))
    ends = np.flatnonzero(np.convolve(pulse, np.ones(window), 'valid') == window) + window
    windows = (np.stack([rows[e - window:e] for e in ends]) if ends.size
               else np.zeros((0, window, 6)))
    return windows, ends - 1


def train_window_vae(train: np.ndarray, ends: np.ndarray, cfg: EstimatorAdaptConfig,
                     seed: int = 0, show_progress: bool = False
                     ) -> tuple[ConditionalVAE, dict]:
    """The conditional VAE on windows (B, w, 6) in time order, ending at periods ``ends``
    (B,), without labels, with its surrogate coordinate chosen (over the changes between
    windows of consecutive periods) and standardized over them; returns it and its
    scores."""
    norm = Normalizer.fit(train[..., 0], train[..., 1])
    config = VAEConfig(window=train.shape[1], latent=cfg.latent, conditional=True,
                       beta=cfg.beta, normalizer=norm.to_dict())
    model = ConditionalVAE(config, generator=torch.Generator().manual_seed(seed))
    history = fit(model, model.loss, train.astype(np.float32), cfg.epochs, seed=seed,
                  desc='adapt estimator', show_progress=show_progress)
    model.eval()
    with torch.no_grad():
        mu, logvar = (v.numpy() for v in model.encode(torch.as_tensor(train,
                                                                      dtype=torch.float32)))
    dim, scores = label_free_choice(mu, logvar, np.diff(ends) == 1)
    model.config = replace(config, surrogate_dim=dim, surrogate_mean=float(mu[:, dim].mean()),
                           surrogate_std=float(mu[:, dim].std() or 1.0))
    return model, {'surrogate_dim': dim, **scores, 'final_loss': history[-1]}


def vae_loss(model: ConditionalVAE, windows: np.ndarray, seed: int = 0) -> float:
    """The VAE's loss (negative ELBO per window) on ``windows`` (B, w, 6)."""
    with torch.no_grad():
        loss, _ = model.loss(torch.as_tensor(windows, dtype=torch.float32),
                             torch.Generator().manual_seed(seed))
    return float(loss)


def fit_laser_map(model: ConditionalVAE, windows: np.ndarray, cfg: EstimatorAdaptConfig,
                  seed: int = 0) -> tuple[KMap, dict]:
    """The K-to-angles map from ``model``'s surrogate of ``windows`` (B, w, 6) to the
    angles at which the laser showed the highest O, by the subset rule; its scores."""
    last = windows[:, -1]
    surrogate = surrogate_of(model, windows)
    centres, targets, target_o = training_subset(surrogate, last[:, 0] / last[:, 1],
                                                 last[:, 2:6], cfg.rule)
    kmap, losses = train_kmap(centres, targets, KMapConfig(), seed=seed, steps=cfg.map_steps)
    return kmap, {'subset_size': int(centres.size), 'final_loss': losses[-1],
                  'subset_mean_O_of_laser': float(target_o.mean())}


def calibrate_estimator(states: np.ndarray, out: Path, cfg: EstimatorAdaptConfig, *,
                        period: int, round_trips: int, pulse_fraction: float,
                        validation: float, seed: int = 0, show_progress: bool = False
                        ) -> dict:
    """Learn this laser's estimator and map from its ``/laser/state`` messages (n, 10) and
    write them into the models folder ``out`` (``vae.pt``, ``vae_encoder.*``, ``kmap.pt``;
    the map keeps the shipped map's ``subset_mean_O``, which sets the lock threshold). The
    windows of the run's last ``validation`` share are held out of training and scored.
    With fewer than ``cfg.min_windows`` training windows ``out`` keeps the shipped ones.
    Returns the report (``kept``: whether they were written)."""
    rows = period_rows(states, period, round_trips)
    windows, ends = pulse_windows(rows, cfg.window, pulse_fraction)
    cut = int(round((1 - validation) * len(windows)))
    train, held = windows[:cut], windows[cut:]
    report: dict = {'periods': int(len(rows)), 'windows': int(cut),
                    'held_out_windows': int(len(held)), 'window': cfg.window}
    if cut < cfg.min_windows or not len(held):
        return {**report, 'kept': False,
                'why': f'{cut} windows of {cfg.window} periods with a pulse to train on, '
                       f'{cfg.min_windows} needed: the shipped estimator stays'}
    model, scores = train_window_vae(train, ends[:cut], cfg, seed, show_progress)
    kmap, map_scores = fit_laser_map(model, train, cfg, seed)
    _, shipped_payload = load_kmap(out / 'kmap.pt')
    report.update(scores, kept=True, map=map_scores,
                  train_loss=vae_loss(model, train, seed),
                  held_out_loss=vae_loss(model, held, seed))
    fingerprint = fingerprint_arrays({'windows': train})
    save_checkpoint(out / 'vae.pt', 'vae', model.state_dict(), model.config.to_dict(),
                    {'adapted': report}, fingerprint)
    export_encoder(model, out, {'made_by': 'dlmpc-train adapt', 'of': 'vae.pt',
                                'data_fingerprint': fingerprint})
    metrics = {'subset_mean_O': shipped_payload['metrics']['subset_mean_O'],
               'adapted': report}
    save_checkpoint(out / 'kmap.pt', 'kmap', kmap.state_dict(), kmap.config.to_dict(),
                    metrics, fingerprint)
    return report
