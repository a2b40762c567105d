"""The birefringence estimator at run time: the VAE over the latest measurements."""

from __future__ import annotations

from collections import deque

import numpy as np
import torch

from dlmpc_ros.learning.vae import ConditionalVAE


class SurrogateEstimator:
    """Feeds a sliding window of measurements to the VAE encoder.

    Parameters
    ----------
    vae
        The trained estimator (its config says the window length w).
    """

    def __init__(self, vae: ConditionalVAE) -> None:
        self.vae = vae
        self.window: deque[np.ndarray] = deque(maxlen=vae.config.window)

    @property
    def ready(self) -> bool:
        return len(self.window) == self.window.maxlen

    def update(self, measurement: np.ndarray) -> tuple[float, np.ndarray] | None:
        """Add a measurement (6,) ``(E, M, alpha[4])``; return ``(surrogate, latent mean)``
        once w measurements are in (until then the window is padded with the oldest)."""
        self.window.append(np.asarray(measurement, np.float32))
        rows = list(self.window)
        rows = [rows[0]] * (self.window.maxlen - len(rows)) + rows
        x = torch.as_tensor(np.stack(rows))[None]                       # (1, w, 6)
        with torch.no_grad():
            mu, _ = self.vae.encode(x)
        return float(self.vae.surrogate(x)[0]), mu[0].numpy()

    def reset(self) -> None:
        self.window.clear()
