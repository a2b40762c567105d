"""``dlmpc-train kmap``: the K-to-angles map and its training pairs.

Training pairs follow the paper's subset rule: the surrogate range is cut into equal
intervals, and within +-delta of each interval's centre the steady state with the
highest objective gives the target angles. Where neighbouring intervals' best angles lie
on different branches, a network fit through them would average incompatible settings;
so among each interval's top candidates the chosen sequence maximizes the summed O minus
a penalty on the angle jump between neighbours (:func:`~dlmpc_ros.training.search.
best_path`). The map is fit with Adam on the L2 loss of its sin/cos features.

The shipped rule (:data:`SHIPPED_RULE`, a strong jump penalty: one branch-continuous
curve) was chosen in closed loop among the candidates of ``bench/kmap_rules.py``
(``docs/results/kmap-rules.md``), where the one-shot figures below did not rank the
rules right.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from dlmpc_ros.core import checks
from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.fingerprint import fingerprint_arrays
from dlmpc_ros.core.steady import run_to_steady
from dlmpc_ros.learning.checkpoint import save_checkpoint
from dlmpc_ros.learning.features import angle_features, measurements
from dlmpc_ros.learning.kmap import KMap, KMapConfig
from dlmpc_ros.learning.tables import load_envelope
from dlmpc_ros.learning.vae import ConditionalVAE, load_vae, steady_windows, surrogate_of
from dlmpc_ros.training import shards
from dlmpc_ros.training.search import best_path
from dlmpc_ros.training.workspace import Workspace


@dataclass(frozen=True)
class SubsetRule:
    """The interval subset rule of the map's training pairs."""

    intervals: int = 61
    """Equal intervals over the surrogate's range (>= 2)."""
    delta: float = 0.75
    """Half-width of the neighbourhood of each interval's centre, in interval widths."""
    top: int = 5
    """Highest-O candidates per interval the dynamic program chooses among."""
    jump_penalty: float = 0.02
    """Cost per unit of sin/cos feature jump between neighbouring intervals, in O."""
    low_quantile: float = 0.005
    """The surrogate's range runs from this quantile to one minus it."""

    def __post_init__(self) -> None:
        checks.counts(self, 'intervals', minimum=2)
        checks.counts(self, 'top')
        checks.positive(self, 'delta')
        checks.non_negative(self, 'jump_penalty')
        if not 0 <= self.low_quantile < 0.5:
            raise ValueError(f'SubsetRule.low_quantile must be in [0, 0.5), '
                             f'got {self.low_quantile!r}')

    def to_dict(self) -> dict:
        return asdict(self)


#: The rule the shipped map was trained with (docs/results/kmap-rules.md).
SHIPPED_RULE = SubsetRule(intervals=21, delta=1.0, top=50, jump_penalty=10.0)


def training_subset(surrogate: np.ndarray, objective: np.ndarray, angles: np.ndarray,
                    rule: SubsetRule) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pick (surrogate centre, angles, O) per interval; returns (n,), (n, 4), (n,)."""
    lo, hi = np.quantile(surrogate, [rule.low_quantile, 1 - rule.low_quantile])
    centres = np.linspace(lo, hi, rule.intervals)
    half = rule.delta * (hi - lo) / (rule.intervals - 1)
    cand_o, cand_a, keep = [], [], []
    for i, c in enumerate(centres):
        rows = np.flatnonzero(np.abs(surrogate - c) <= half)
        if rows.size == 0:
            continue
        best = rows[np.argsort(objective[rows])[::-1][:rule.top]]
        cand_o.append(objective[best])
        cand_a.append(angles[best])
        keep.append(i)
    feats = [np.concatenate([np.sin(2 * a), np.cos(2 * a)], axis=-1) for a in cand_a]

    def jump_cost(j: int) -> np.ndarray:  # (previous, now)
        jump = np.linalg.norm(feats[j][:, None, :] - feats[j - 1][None, :, :], axis=-1)
        return (rule.jump_penalty * jump).T

    pick = best_path(cand_o, jump_cost)
    chosen_a = np.stack([cand_a[j][p] for j, p in enumerate(pick)])
    chosen_o = np.array([cand_o[j][p] for j, p in enumerate(pick)])
    return centres[keep], chosen_a, chosen_o


def train_kmap(centres: np.ndarray, targets: np.ndarray, config: KMapConfig, seed: int = 0,
               steps: int = 3000, lr: float = 3e-3) -> tuple[KMap, list[float]]:
    """Fit the map to (surrogate, angles) pairs with Adam on the L2 loss of the features
    (full batch, ``steps`` steps)."""
    model = KMap(config, generator=torch.Generator().manual_seed(seed))
    s = torch.as_tensor(centres, dtype=torch.float32)[:, None]
    y = angle_features(torch.as_tensor(targets, dtype=torch.float32))
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    losses = []
    for _ in range(steps):
        optimizer.zero_grad()
        loss = 0.5 * ((model.features(s) - y) ** 2).sum(dim=-1).mean()
        loss.backward()
        optimizer.step()
        losses.append(float(loss.detach()))
    return model, losses


def map_training_pairs(vae: ConditionalVAE, sweep: dict[str, np.ndarray], rule: SubsetRule
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rule's (centres, target angles, target O) from the sweep's steady states, read
    through the estimator's surrogate."""
    steady = sweep['converged'] & sweep['finite']
    s = surrogate_of(vae, steady_windows(measurements(sweep)[steady], vae.config.window))
    return training_subset(s, sweep['O'][steady], sweep['alpha'][steady], rule)


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


def median_states(sweep: dict[str, np.ndarray], k_values: np.ndarray) -> np.ndarray:
    """(n, 4) angles of the median-O converged sweep point at each of ``k_values``: a
    typical state whose angles do not carry K."""
    steady = sweep['converged'] & sweep['finite']
    out = []
    for k in k_values:
        rows = np.flatnonzero(steady & (sweep['K'] == k))
        order = rows[np.argsort(sweep['O'][rows])]
        out.append(sweep['alpha'][order[order.size // 2]])
    return np.stack(out)


def train_kmap_stage(ws: Workspace, seed: int = 0, steps: int = 3000,
                     cavity_cfg: CavityConfig | None = None, rule: SubsetRule = SHIPPED_RULE
                     ) -> dict:
    """Train the map with ``rule``, measure it against the envelope, save it and its
    figure; returns the metrics.

    The map is measured on the envelope's K points by the steady O it reaches from the
    oracle's own state (whose angles carry K; the odd K points are the test figure) and
    from a typical state (the median-O sweep point at each K; the even K points were the
    rules' validation figure)."""
    started = time.monotonic()
    cavity_cfg = cavity_cfg or CavityConfig()
    vae, vae_payload = load_vae(ws.model('vae'))
    sweep = shards.load_dataset(ws.sweep)
    envelope = load_envelope(ws.oracle)
    centres, targets, target_o = map_training_pairs(vae, sweep, rule)
    model, losses = train_kmap(centres, targets, KMapConfig(), seed=seed, steps=steps)
    val, test = np.arange(0, envelope['K'].size, 2), np.arange(1, envelope['K'].size, 2)
    at_median = evaluate_map(vae, model, envelope, cavity_cfg,
                             median_states(sweep, envelope['K']))
    at_oracle = evaluate_map(vae, model, envelope, cavity_cfg, envelope['angles'])
    metrics = {
        'subset_rule': rule.to_dict(), 'subset_size': int(centres.size),
        'validation_ratio_from_median_state': float(np.mean(at_median['ratio'][val])),
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
    save_checkpoint(ws.model('kmap'), 'kmap', model.state_dict(), model.config.to_dict(),
                    metrics, fingerprint_arrays({'centres': centres, 'targets': targets}))
    plot_map(centres, targets, model, envelope, at_oracle, ws.figures / 'kmap.png')
    return metrics


def plot_map(centres: np.ndarray, targets: np.ndarray, model: KMap,
             envelope: dict[str, np.ndarray], result: dict[str, np.ndarray],
             path: Path) -> Path:
    """The map's angles over the surrogate with its targets, and its steady O over K."""
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
