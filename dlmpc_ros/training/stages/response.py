"""``dlmpc-train response``: the DL-MPC's steady-response predictor
(:mod:`dlmpc_ros.learning.response`) from the rotation data of the plant family
(:mod:`dlmpc_ros.training.response`, made here first if ``data/response`` is missing).

Training pairs: along each rotation profile (one plant, K and curve point, the rotation
stepped both ways from 0), every state that holds a pulse (O at least ``pulse_fraction``
of the profile's best) and every other rotation within ``trust`` of it give the inputs
``(u, theta_a, log E_a, log M_a, theta_b - theta_a)`` and the target ``log(O_b / O_a)``,
or :data:`~dlmpc_ros.training.response.LOST` where the pulse is lost on the way. Each
member of the ensemble is fit to its own bootstrap sample of the training plants' pairs;
a fifth of the plants are held out, and the figures are measured on them: the RMSE, and
what one-step plans chosen by the predictor (mean minus ``spread_penalty`` times the
members' spread, within the trust radius) gain against the best turn within it.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from dlmpc_ros.core import checks
from dlmpc_ros.learning.checkpoint import save_checkpoint
from dlmpc_ros.learning.curve import FILE_NAME, load_curve
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.response import FEATURES, ResponseEnsemble
from dlmpc_ros.learning.response_file import ResponseModelConfig
from dlmpc_ros.training import shards
from dlmpc_ros.training.adapt import AdaptConfig, laser_pairs, prediction_rmse
from dlmpc_ros.training.closed_loop import ClosedLoopConfig, closed_loop_runs
from dlmpc_ros.training.response import LOST, ResponseConfig, generate_response
from dlmpc_ros.training.workspace import Workspace


@dataclass(frozen=True)
class PairRule:
    """Which pairs of states along a profile train the predictor."""

    trust: float = 0.2
    """Largest further turn [rad]."""
    pulse_fraction: float = 0.3
    """A state holds a pulse when its O is at least this fraction of its profile's best."""

    def __post_init__(self) -> None:
        checks.positive(self, 'trust')
        checks.fraction(self, 'pulse_fraction')


@dataclass(frozen=True)
class FitSettings:
    """How the ensemble is fit and judged."""

    members: int = 5
    hidden: int = 64
    epochs: int = 12
    batch: int = 1024
    lr: float = 2e-3
    held_out: float = 0.2
    """Fraction of the plants held out for the figures."""
    plan_radius: float = 0.1
    """Trust radius of the one-step plans the figures judge [rad]."""
    spread_penalty: float = 1.0
    """Weight of the members' spread in those plans."""

    def to_dict(self) -> dict:
        return asdict(self)


def profiles(data: dict[str, np.ndarray]) -> list[dict[str, np.ndarray]]:
    """The rotation profiles of the data: per (plant, K, u), the rows sorted by theta."""
    keys = np.stack([data['plant'], data['K'], data['u']], axis=1)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    out = []
    for g in range(int(group.max()) + 1):
        rows = np.flatnonzero(group.ravel() == g)
        rows = rows[np.argsort(data['theta'][rows])]
        out.append({k: v[rows] for k, v in data.items()})
    return out


def profile_pairs(profile: dict[str, np.ndarray], rule: PairRule
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Inputs (m, 5) of :data:`FEATURES` and targets (m,) of one profile's pairs."""
    theta, energy, kurtosis = profile['theta'], profile['E'], profile['M']
    objective = np.where(np.isfinite(energy / kurtosis), energy / kurtosis, 0.0)
    pulse = objective >= rule.pulse_fraction * max(objective.max(), 1e-12)
    x, y = [], []
    for a in np.flatnonzero(pulse):
        near = np.flatnonzero(np.abs(theta - theta[a]) <= rule.trust + 1e-9)
        for b in near:
            path = slice(min(a, b), max(a, b) + 1)
            ratio = (np.log(objective[b] / objective[a]) if pulse[path].all() else LOST)
            x.append((profile['u'][a], theta[a], np.log(energy[a]), np.log(kurtosis[a]),
                      theta[b] - theta[a]))
            y.append(max(ratio, LOST))
    return np.asarray(x, float).reshape(-1, len(FEATURES)), np.asarray(y, float)


def plan_figures(model: ResponseEnsemble, held_out: list[dict[str, np.ndarray]],
                 rule: PairRule, settings: FitSettings) -> dict:
    """One-step plans from every pulse state of the held-out profiles: the predictor's
    choice within ``plan_radius`` against the best turn there and against holding."""
    chosen, best, lost = [], [], 0
    for profile in held_out:
        x, y = profile_pairs(profile, PairRule(settings.plan_radius, rule.pulse_fraction))
        starts = np.unique(x[:, :4], axis=0)
        for state in starts:
            rows = np.flatnonzero(np.all(x[:, :4] == state, axis=1))
            mean, spread = model.predict(state[0], state[1], np.exp(state[2]),
                                         np.exp(state[3]), x[rows, 4])
            pick = rows[int(np.argmax(mean - settings.spread_penalty * spread))]
            chosen.append(y[pick])
            best.append(y[rows].max())
            lost += int(y[pick] <= LOST)
    chosen, best = np.array(chosen), np.array(best)
    return {'plans': int(chosen.size),
            'mean_gain_chosen': float(np.mean(np.exp(chosen) - 1)),
            'mean_gain_best': float(np.mean(np.exp(best) - 1)),
            'share_of_best_gain': float(np.sum(np.exp(chosen) - 1)
                                        / max(np.sum(np.exp(best) - 1), 1e-12)),
            'plans_that_lose_the_pulse': lost}


def split_pairs(data: dict[str, np.ndarray], rule: PairRule, held_out: float
                ) -> tuple[np.ndarray, np.ndarray, list[dict], list[dict]]:
    """The training pairs (inputs (m, 5), targets (m,)) of the rotation data's plants but
    the last ``held_out`` share, and the training and held-out plants' profiles."""
    plants = np.unique(data['plant'])
    n_held = max(1, int(round(held_out * plants.size))) if plants.size > 1 else 0
    held = set(plants[plants.size - n_held:].tolist())
    train_profiles, held_profiles = [], []
    for profile in profiles(data):
        (held_profiles if int(profile['plant'][0]) in held else train_profiles).append(profile)
    x, y = joined_pairs([profile_pairs(p, rule) for p in train_profiles])
    return x, y, train_profiles, held_profiles


def fit_ensemble(x: np.ndarray, y: np.ndarray, settings: FitSettings, seed: int,
                 show_progress: bool = True) -> tuple[ResponseEnsemble, list]:
    """A new ensemble, its input scaling from ``x`` (m, 5), each member fit to its own
    bootstrap sample of the pairs ``(x, y)``; returns it (in eval mode) and the members'
    loss histories."""
    config = ResponseModelConfig(members=settings.members, hidden=settings.hidden,
                                 mean=x.mean(0).tolist(),
                                 std=np.maximum(x.std(0), 1e-6).tolist())
    generator = torch.Generator().manual_seed(seed)
    model = ResponseEnsemble(config, generator)
    samples = torch.as_tensor(np.c_[x, y], dtype=torch.float32)
    histories = []
    for m, member in enumerate(model.members):
        pick = torch.randint(samples.shape[0], (samples.shape[0],), generator=generator)

        def loss_fn(batch: torch.Tensor, _g, member=member) -> tuple[torch.Tensor, dict]:
            z = (batch[:, :-1] - model.mean) / model.std
            return torch.mean((member(z)[:, 0] - batch[:, -1]) ** 2), {}
        histories.append(fit(member, loss_fn, samples[pick], settings.epochs,
                             settings.batch, settings.lr, seed + m, cosine=True,
                             desc=f'response member {m + 1}', show_progress=show_progress))
    model.eval()
    return model, histories


def train_response_stage(ws: Workspace, seed: int, quick: bool = False,
                         show_progress: bool = True, workers: int = 1,
                         data_cfg: ResponseConfig | None = None,
                         closed_loop: bool = True) -> dict:
    """Make the data if needed (``data_cfg``, default the shipped settings), fit the
    ensemble, write ``models/response.pt``; with ``closed_loop``, then run the exploring
    DL-MPC on training plants (:mod:`dlmpc_ros.training.closed_loop`, runs kept in
    ``data/response_closed_loop``) and fit the ensemble again to the rotation pairs and
    those runs' pairs. Returns the stage's metrics."""
    started = time.monotonic()
    grid, angles, _ = load_curve(ws.models_dir / FILE_NAME)
    if data_cfg is None:
        data_cfg = (ResponseConfig(plants=6, k_values=(-0.25, -0.1), offsets=(0.0,), steps=8,
                                   settle=150, plants_per_task=3)
                    if quick else ResponseConfig())
    meta = generate_response(ws.response, data_cfg, grid, angles, show_progress, workers)
    data = shards.load_dataset(ws.response)
    rule, settings = PairRule(), FitSettings(epochs=2 if quick else FitSettings.epochs)
    plants = np.unique(data['plant'])
    x, y, train_profiles, held_profiles = split_pairs(data, rule, settings.held_out)
    held = sorted({int(p['plant'][0]) for p in held_profiles})
    judged_on = 'held-out plants' if held_profiles else 'the training plant (only one)'
    held_profiles = held_profiles or train_profiles
    model, histories = fit_ensemble(x, y, settings, seed, show_progress)
    metrics = {
        'data': {'plants': int(plants.size), 'held_out_plants': held,
                 'rows': int(data['plant'].size), 'training_pairs': int(y.size),
                 'fingerprint': meta['fingerprint'], 'settings': data_cfg.to_dict()},
        'fit': settings.to_dict(), 'pairs': asdict(rule),
        'loss_history': [h[-1] for h in histories],
        **rotation_figures(model, held_profiles, rule, settings), 'figures_on': judged_on,
    }
    if closed_loop:   # the exploring controller loads models_dir, response.pt included
        save_checkpoint(ws.model('response'), 'response', model.state_dict(),
                        model.config.to_dict(), metrics, meta['fingerprint'])
        cfg = (ClosedLoopConfig(plants=2, validation_plants=1, round_trips=1500)
               if quick else ClosedLoopConfig())
        runs = closed_loop_runs(cfg, ws.models_dir, ws.response_closed_loop, workers,
                                show_progress=show_progress)
        pairs = [laser_pairs(run, grid, angles, AdaptConfig())[:2] for run in runs]
        cut = cfg.plants - cfg.validation_plants
        cx, cy = joined_pairs(pairs[:cut])
        vx, vy = joined_pairs(pairs[cut:])
        before = {'fit': prediction_rmse(model, cx, cy) if cy.size else None,
                  'held_out_plants': prediction_rmse(model, vx, vy) if vy.size else None}
        model, histories = fit_ensemble(np.r_[x, cx], np.r_[y, cy], settings, seed,
                                        show_progress)
        metrics['closed_loop'] = {
            'settings': cfg.to_dict(), 'pairs': int(cy.size), 'held_out_pairs': int(vy.size),
            'held_out_plants': cfg.seeds[cut:],
            'rmse_pretrained': before,
            'rmse': {'fit': prediction_rmse(model, cx, cy) if cy.size else None,
                     'held_out_plants': prediction_rmse(model, vx, vy) if vy.size else None},
            'rotation_data_only': {k: metrics[k] for k in (
                'loss_history', 'heldout_rmse_log_ratio', 'heldout_rmse_where_kept',
                'heldout_plans')}}
        metrics.update(loss_history=[h[-1] for h in histories],
                       **rotation_figures(model, held_profiles, rule, settings))
        metrics['data']['training_pairs'] = int(y.size + cy.size)
    metrics['wall_seconds'] = round(time.monotonic() - started, 1)
    save_checkpoint(ws.model('response'), 'response', model.state_dict(), model.config.to_dict(),
                    metrics, meta['fingerprint'])
    return metrics


def rotation_figures(model: ResponseEnsemble, held_profiles: list[dict[str, np.ndarray]],
                     rule: PairRule, settings: FitSettings) -> dict:
    """The RMSEs of the predicted change of log O on the held-out profiles' pairs (all of
    them; where the pulse is kept) and the one-step plans' figures there."""
    hx, hy = joined_pairs([profile_pairs(p, rule) for p in held_profiles])
    with torch.no_grad():
        predicted = model(torch.as_tensor(hx, dtype=torch.float32)).mean(-1).numpy()
    return {'heldout_rmse_log_ratio': float(np.sqrt(np.mean((predicted - hy) ** 2))),
            'heldout_rmse_where_kept': float(np.sqrt(np.mean(((predicted - hy) ** 2)[hy > LOST]))),
            'heldout_plans': plan_figures(model, held_profiles, rule, settings)}


def joined_pairs(pairs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The inputs (m, 5) and targets (m,) of several profiles' or runs' pairs, one after
    the other (none: empty arrays)."""
    if not pairs:
        return np.empty((0, len(FEATURES))), np.empty(0)
    return np.concatenate([q[0] for q in pairs]), np.concatenate([q[1] for q in pairs])
