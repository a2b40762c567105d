"""Plots of recorded runs (reads CSV files only; never imported by the solver)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def load_run_csv(path: Path) -> dict[str, np.ndarray]:
    """Columns of a bringup CSV (``round_trip, E, M, O, ..., K``) as arrays."""
    from dlmpc_ros.recording.run_csv import read_run_csv
    return read_run_csv(path)


def plot_run(run: dict[str, np.ndarray], ax=None):
    """O (left axis) and K (right axis) over round trips; returns the two axes."""
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    ax.plot(run['round_trip'], run['O'], color='tab:blue', lw=0.8, label='objective O = E/M')
    ax.set_xlabel('round trip')
    ax.set_ylabel('O = E / M', color='tab:blue')
    ax_k = ax.twinx()
    ax_k.plot(run['round_trip'], run['K'], color='tab:red', lw=1.0, label='birefringence K')
    ax_k.set_ylabel('K (true, drifting)', color='tab:red')
    ax.grid(alpha=0.3)
    return ax, ax_k


def plot_run_csv(csv_path: Path, png_path: Path) -> Path:
    """Plot a bringup CSV to a PNG file."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    ax, _ = plot_run(load_run_csv(csv_path))
    ax.set_title(f'{Path(csv_path).name}: objective and birefringence')
    png_path.parent.mkdir(parents=True, exist_ok=True)
    ax.figure.savefig(png_path, dpi=120)
    plt.close(ax.figure)
    return png_path
