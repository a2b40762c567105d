"""The periodic time grid and its wavenumbers (numpy ``fftfreq`` order)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dlmpc_ros.core.config import CavityConfig


@dataclass(frozen=True)
class Grid:
    """Time grid ``t_j = -T/2 + j T/n`` (the endpoint is not a grid point) and wavenumbers.

    Attributes
    ----------
    t_grid
        (n,) time points.
    k_grid
        (n,) angular wavenumbers ``(2 pi / T) * fftfreq index``.
    mode_index
        (n,) absolute integer mode index ``|m|`` with ``k = (2 pi / T) m``.
    dt
        Grid spacing ``T / n``.
    """

    t_grid: np.ndarray
    k_grid: np.ndarray
    mode_index: np.ndarray
    dt: float

    @classmethod
    def from_config(cls, config: CavityConfig) -> Grid:
        n, window = config.points, config.window
        dt = window / n
        index = np.fft.fftfreq(n, d=1.0 / n)  # 0, 1, ..., -1 as floats
        return cls(
            t_grid=-window / 2 + np.arange(n) * dt,
            k_grid=(2 * np.pi / window) * index,
            mode_index=np.abs(index).astype(np.int64),
            dt=dt,
        )

    @property
    def points(self) -> int:
        return self.t_grid.shape[0]
