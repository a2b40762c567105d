"""Figures of closed-loop runs (reads run records only; matplotlib imported lazily).

- :func:`plot_tracking` (the paper's Figs. 5 and 6): O of every controller against the
  oracle envelope O*(K(t)), K over time, and the angles one controller set.
- :func:`plot_surrogate` (the paper's Fig. 4): the estimator's surrogate against K.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.control.step import MODES
from dlmpc_ros.evaluation.record import RunRecord
from dlmpc_ros.learning.tables import envelope_objective

ANGLE_NAMES = ('alpha1', 'alpha2', 'alpha3', 'alpha_p')


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Running mean over ``width`` samples, of the samples there are (edges, NaN)."""
    if width <= 1 or x.size < width:
        return x
    valid = np.isfinite(x)
    window = np.ones(width)
    total = np.convolve(np.where(valid, x, 0.0), window, mode='same')
    count = np.convolve(valid.astype(float), window, mode='same')
    return np.where(count > 0, total / np.maximum(count, 1.0), np.nan)


def plot_tracking(records: dict[str, RunRecord], envelope: dict[str, np.ndarray] | None,
                  angles_of: str, title: str, path: Path) -> Path:
    """Three panels over round trips: O per controller (smoothed over 50 round trips) and
    O*(K) (``envelope`` None: not drawn); K with the curve tracker's estimate of
    ``angles_of`` where it tracked; the angles ``angles_of`` commanded."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 8), sharex=True, constrained_layout=True)
    any_record = next(iter(records.values()))
    r = any_record.round_trip
    if envelope is not None:
        axes[0].plot(r, envelope_objective(envelope, any_record.K), color='k', lw=1.2,
                     ls='--', label='envelope O*(K(t))')
    for name, record in records.items():
        axes[0].plot(record.round_trip, _smooth(record.O, 50), lw=1.0, label=name)
    axes[0].set_ylabel('O = E/M')
    axes[0].legend(ncol=3, fontsize=8, loc='lower right')
    axes[1].plot(r, any_record.K, color='tab:red', label='K (true, never measured)')
    shown = records.get(angles_of, any_record)
    track = _tracking(shown) & np.isfinite(shown.surrogate)
    if track.any():
        axes[1].plot(shown.control_round_trip[track], shown.surrogate[track], '.', ms=1.5,
                     color='black', label=f'estimate of {angles_of} (curve tracker)')
    axes[1].set_ylabel('K')
    axes[1].legend(fontsize=8, loc='upper right')
    for i, name in enumerate(ANGLE_NAMES):
        axes[2].plot(shown.round_trip, shown.angles[:, i], lw=0.9, label=name)
    axes[2].set_ylabel(f'angles of {angles_of} [rad]')
    axes[2].set_xlabel('round trip')
    axes[2].legend(ncol=4, fontsize=8)
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[0].set_title(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _tracking(record: RunRecord) -> np.ndarray:
    """(periods,) True where the DL-MPC tracked the curve (and where its planner turned
    it): its status surrogate there is the curve estimate (K's units), not the VAE
    surrogate."""
    return np.isin(record.mode, [MODES.index('track'), MODES.index('plan')])


def surrogate_correlation(record: RunRecord, tracking: bool = False,
                          estimator: bool = False) -> float | None:
    """|Pearson r| between the true K and, at the control periods, the surrogate the
    controller used (the VAE's, ``tracking`` False, or the curve tracker's estimate,
    True), or with ``estimator`` the estimator's own surrogate in those same periods."""
    values = record.estimate if estimator else record.surrogate
    ok = np.isfinite(values) & (_tracking(record) == tracking)
    if ok.sum() < 3:
        return None
    index = np.searchsorted(record.round_trip, record.control_round_trip[ok])
    k = record.K[np.clip(index, 0, record.K.size - 1)]
    if np.std(k) == 0 or np.std(values[ok]) == 0:
        return None
    return float(abs(np.corrcoef(values[ok], k)[0, 1]))


def plot_surrogate(record: RunRecord, title: str, path: Path) -> Path:
    """The surrogate and the true K over time (twin axes), with |r| in the title."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 3.5), constrained_layout=True)
    track = _tracking(record)
    ax.plot(record.control_round_trip, np.where(track, np.nan, record.surrogate), lw=0.7,
            color='tab:blue', label='VAE surrogate')
    ax.set_ylabel('VAE surrogate', color='tab:blue')
    ax.set_xlabel('round trip')
    twin = ax.twinx()
    twin.plot(record.round_trip, record.K, color='tab:red', lw=1.0, label='true K')
    if track.any():
        twin.plot(record.control_round_trip[track], record.surrogate[track], '.', ms=1.5,
                  color='black', label='curve estimate (track)')
        twin.legend(loc='upper right', fontsize=8)
    twin.set_ylabel('K (true) and curve estimate', color='tab:red')
    r, r_track = surrogate_correlation(record), surrogate_correlation(record, tracking=True)
    parts = [f'VAE |r| = {r:.3f}' if r is not None else '',
             f'curve estimate |r| = {r_track:.3f}' if r_track is not None else '']
    parts = [p for p in parts if p]
    ax.set_title(f'{title}: {", ".join(parts)}' if parts else title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
