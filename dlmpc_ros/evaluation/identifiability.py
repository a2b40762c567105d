"""Where the estimator's K surrogate gets its information from (an evaluation; reads true K).

The estimator sees ``(E, M, alpha)``. On the drift trajectories the data policy steers the
angles toward good settings for the current K, so the angles alone correlate with K, and a
surrogate can follow K there without reading the laser at all. These checks tell the two
apart:

- the surrogate on the held-out trajectories as they are, with E and M frozen at their
  medians (what the angles alone give), and with the angles frozen (what E and M give);
- the surrogate on the steady-state sweep, whose angle sets are crossed with every K, so
  that the angles say little about K there;
- supervised probes, for comparison only: a small network trained *on K* (never shipped)
  shows how much of K any function of one measurement recovers, from the angles, from
  (E, M), and from both.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from dlmpc_ros.core import checks
from dlmpc_ros.learning.features import Normalizer, features, measurements
from dlmpc_ros.learning.fit import fit
from dlmpc_ros.learning.seeding import reset_linear_layers
from dlmpc_ros.learning.vae import ConditionalVAE, steady_windows, surrogate_of, windows

#: Surrogate of single measurements: (N, 6) ``(E, M, 4 angles)`` -> (N,).
SurrogateFn = Callable[[np.ndarray], np.ndarray]


def abs_r(a: np.ndarray, b: np.ndarray) -> float:
    """|Pearson r| of two equally long series (0 when either is constant)."""
    a, b = np.ravel(a), np.ravel(b)
    if a.std() == 0 or b.std() == 0:
        return 0.0
    return float(abs(np.corrcoef(a, b)[0, 1]))


#: Columns of a measurement (N, 6).
E_M, ANGLES = slice(0, 2), slice(2, 6)


def frozen(measured: np.ndarray, columns: slice) -> np.ndarray:
    """A copy of measurements (N, 6) with ``columns`` held at their medians."""
    out = measured.copy()
    out[:, columns] = np.median(measured[:, columns], axis=0)
    return out


def surrogate_sources(surrogate: SurrogateFn, trajectories: np.ndarray, k_traj: np.ndarray,
                      sweep: np.ndarray, k_sweep: np.ndarray) -> dict[str, float]:
    """|r| between surrogate and true K with each input source on its own.

    trajectories: (N, 6) held-out trajectory measurements with true K ``k_traj`` (N,);
    sweep: (S, 6) steady states of the sweep with their K ``k_sweep`` (S,).
    """
    return {
        'trajectories': abs_r(surrogate(trajectories), k_traj),
        'trajectories_angles_only': abs_r(surrogate(frozen(trajectories, E_M)), k_traj),
        'trajectories_E_M_only': abs_r(surrogate(frozen(trajectories, ANGLES)), k_traj),
        'sweep': abs_r(surrogate(sweep), k_sweep),
    }


@dataclass(frozen=True)
class ProbeConfig:
    """A supervised probe: MLP from one measurement's features to K (comparison only)."""

    hidden: int = 128
    """Units of its two hidden layers."""
    epochs: int = 40
    """Passes over the training samples."""
    batch: int = 256
    """Samples per Adam step."""
    lr: float = 1e-3
    """Adam learning rate."""
    seed: int = 0
    """Seed of the initial weights, the sample order and the sweep's splits."""
    window: int = 16
    """Length of the windowed probe on the trajectories [control periods]."""

    def __post_init__(self) -> None:
        checks.counts(self, 'hidden', 'epochs', 'batch', 'window')
        checks.counts(self, 'seed', minimum=0)
        checks.positive(self, 'lr')


#: Feature columns of :func:`features` each probe reads.
PROBE_INPUTS = {'angles': slice(2, 10), 'E_M': slice(0, 2), 'all': slice(0, 10)}


def probe_r(measured: np.ndarray, k: np.ndarray, train: np.ndarray, norm: Normalizer,
            inputs: str = 'all', config: ProbeConfig = ProbeConfig()) -> float:
    """|r| on the samples outside ``train`` of an MLP fitted to K on those inside.

    measured: (N, 6), or (N, w, 6) windows (K of the last row); k: (N,) true K; train: (N,)
    booleans.
    """
    x = features(torch.as_tensor(measured, dtype=torch.float64), norm)[..., PROBE_INPUTS[inputs]]
    x = x.flatten(1).float()
    scale = float(np.std(k[train])) or 1.0
    y = torch.as_tensor(k / scale, dtype=torch.float32)
    net = reset_linear_layers(nn.Sequential(nn.Linear(x.shape[1], config.hidden), nn.ReLU(),
                                            nn.Linear(config.hidden, config.hidden), nn.ReLU(),
                                            nn.Linear(config.hidden, 1)),
                              torch.Generator().manual_seed(config.seed))
    data = torch.cat([x, y[:, None]], dim=1)[torch.as_tensor(np.flatnonzero(train))]

    def loss(batch: torch.Tensor, _generator) -> tuple[torch.Tensor, dict]:
        return ((net(batch[:, :-1])[:, 0] - batch[:, -1]) ** 2).mean(), {}

    fit(net, loss, data.numpy(), config.epochs, batch=config.batch, lr=config.lr,
        seed=config.seed, show_progress=False)
    with torch.no_grad():
        predicted = net(x[torch.as_tensor(np.flatnonzero(~train))])[:, 0].numpy()
    return abs_r(predicted, k[~train])


def probe_table(measured: np.ndarray, k: np.ndarray, train: np.ndarray, norm: Normalizer,
                subsets: dict[str, np.ndarray], config: ProbeConfig = ProbeConfig()
                ) -> dict[str, dict[str, float]]:
    """``{subset: {inputs: |r|}}`` of probes on each subset (N,) mask of the samples."""
    return {name: {inputs: probe_r(measured[mask], k[mask], train[mask], norm, inputs, config)
                   for inputs in PROBE_INPUTS}
            for name, mask in subsets.items()}


# -- the check on shipped models and datasets -----------------------------------------------

def check_estimator(vae: ConditionalVAE, trajectories: dict[str, np.ndarray],
                    sweep: dict[str, np.ndarray], out_dir: Path,
                    config: ProbeConfig = ProbeConfig(), show_progress: bool = True) -> dict:
    """Run every check on an estimator, the trajectories (with their ``held_out`` lanes)
    and the sweep; write ``metrics.json``, ``report.md`` and ``surrogate_sources.png``
    into ``out_dir``; returns the metrics."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)

    def surrogate(measured: np.ndarray) -> np.ndarray:
        return surrogate_of(vae, steady_windows(measured, vae.config.window))

    traj = trajectories
    held_out = traj['held_out']
    steps = traj['K'].shape[1]
    traj_measured = measurements(traj).reshape(-1, 6)
    traj_k = traj['K'].reshape(-1)
    traj_train = np.repeat(~held_out, steps)
    steady = sweep['converged'] & sweep['finite']
    sweep_measured, sweep_k = measurements(sweep)[steady], sweep['K'][steady]
    sweep_train = np.random.default_rng(config.seed).random(sweep_k.size) < 0.8
    # the same share of whole angle sets (chains) held out: K at angles never seen in training
    chain = sweep['chain'][steady]
    set_train = np.random.default_rng(config.seed).random(int(chain.max()) + 1)[chain] < 0.8
    norm = Normalizer(**vae.config.normalizer)
    if vae.config.window != 1 and show_progress:
        print(f'note: a window-{vae.config.window} model sees each measurement repeated '
              'over its window here', flush=True)
    sources = surrogate_sources(surrogate, traj_measured[~traj_train], traj_k[~traj_train],
                                sweep_measured, sweep_k)
    if show_progress:
        print('surrogate |r|:', {k: round(v, 3) for k, v in sources.items()}, flush=True)
    pulsed = sweep['pulses'][steady] >= 1
    w = config.window
    traj_windows = windows(measurements(traj), w)  # (lanes * (steps - w + 1), w, 6)
    window_train = np.repeat(~held_out, steps - w + 1)
    probes = {'trajectories': probe_table(traj_measured, traj_k, traj_train, norm,
                                          {'all samples': np.ones(traj_k.size, bool)}, config),
              f'trajectories, windows of {w}': probe_table(
                  traj_windows, traj['K'][:, w - 1:].reshape(-1), window_train, norm,
                  {'all samples': np.ones(window_train.size, bool)}, config),
              'sweep': probe_table(sweep_measured, sweep_k, sweep_train, norm,
                                   {'all samples': np.ones(sweep_k.size, bool),
                                    'pulsed (1+ pulses)': pulsed,
                                    'continuous wave': ~pulsed}, config),
              'sweep, held-out angle sets': probe_table(
                  sweep_measured, sweep_k, set_train, norm,
                  {'all samples': np.ones(sweep_k.size, bool)}, config)}
    if show_progress:
        print('probe |r|:', json.dumps(probes), flush=True)
    result = {'surrogate_abs_r': sources, 'supervised_probe_abs_r': probes,
              'probe_config': asdict(config),
              'samples': {'trajectories_held_out': int((~traj_train).sum()),
                          'sweep': int(sweep_k.size), 'sweep_pulsed': int(pulsed.sum())}}
    (out_dir / 'metrics.json').write_text(json.dumps(result, indent=1))
    (out_dir / 'report.md').write_text(_report(result))
    _plot(surrogate, traj_measured[~traj_train], traj_k[~traj_train], sweep_measured, sweep_k,
          out_dir / 'surrogate_sources.png')
    return result


def _report(result: dict) -> str:
    s = result['surrogate_abs_r']
    lines = ['# Where the K surrogate comes from', '',
             'Made by `dlmpc-train check-estimator`. |Pearson r| against the true K.', '',
             '| shipped VAE surrogate on | abs r |', '|---|---|',
             f"| held-out trajectories | {s['trajectories']:.3f} |",
             f"| same, E and M frozen at their medians (angles only) | "
             f"{s['trajectories_angles_only']:.3f} |",
             f"| same, angles frozen at their medians (E and M only) | "
             f"{s['trajectories_E_M_only']:.3f} |",
             f"| steady-state sweep (angle sets crossed with K) | {s['sweep']:.3f} |", '',
             'Supervised probes (an MLP trained on K for this comparison; never shipped), '
             'abs r on held-out samples:', '', '| data | samples | angles | E, M | all |',
             '|---|---|---|---|---|']
    for data, table in result['supervised_probe_abs_r'].items():
        for subset, row in table.items():
            lines.append(f"| {data} | {subset} | {row['angles']:.3f} | {row['E_M']:.3f} | "
                         f"{row['all']:.3f} |")
    return '\n'.join(lines) + '\n'


def _plot(surrogate: SurrogateFn, traj: np.ndarray, k_traj: np.ndarray, sweep: np.ndarray,
          k_sweep: np.ndarray, path: Path, points: int = 4000) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    panels = [('held-out trajectories', traj, k_traj),
              ('trajectories, E and M frozen', frozen(traj, E_M), k_traj),
              ('steady-state sweep', sweep, k_sweep)]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, (title, measured, k) in zip(axes, panels):
        pick = rng.choice(k.size, size=min(points, k.size), replace=False)
        s = surrogate(measured[pick])
        ax.scatter(k[pick], s, s=2, alpha=0.4)
        ax.set_title(f'{title}\n|r| = {abs_r(s, k[pick]):.2f}', fontsize=9)
        ax.set_xlabel('true K')
    axes[0].set_ylabel('surrogate (standardized)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
