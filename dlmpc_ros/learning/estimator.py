"""The birefringence estimator at run time: the VAE's encoder over the latest measurements
(numpy only: :mod:`dlmpc_ros.learning.encoder`)."""

from __future__ import annotations

from collections import deque

import numpy as np

from dlmpc_ros.learning.encoder import Encoder


class SurrogateEstimator:
    """Feeds a sliding window of measurements to the VAE's ``encoder`` (window length w)."""

    def __init__(self, encoder: Encoder) -> None:
        self.encoder = encoder
        self.window: deque[np.ndarray] = deque(maxlen=encoder.window)

    def update(self, measurement: np.ndarray) -> tuple[float, np.ndarray]:
        """Add a measurement (6,) ``(E, M, alpha[4])``; return ``(surrogate, latent mean)``
        (a window short of w is padded with the oldest)."""
        self.window.append(np.asarray(measurement, np.float32))
        rows = list(self.window)
        rows = [rows[0]] * (self.window.maxlen - len(rows)) + rows
        x = np.stack(rows)[None]                                        # (1, w, 6)
        return float(self.encoder.surrogate(x)[0]), self.encoder.mean(x)[0]

    def reset(self) -> None:
        self.window.clear()
