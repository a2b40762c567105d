"""Network features of the measured laser signals, and their normalization.

A measurement at control step t is ``(E, M, alpha1, alpha2, alpha3, alpha_p)``. Networks
see ``(E_n, logM_n, sin 2 alpha (4), cos 2 alpha (4))``: the angles enter through
pi-periodic features (every Jones element is pi-periodic in its angle), the kurtosis
through its logarithm (it spans 15 to 254), and E and log M standardized by the training
data's statistics, which are stored with every model.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch

from dlmpc_ros.core import checks

N_MEASURED = 6  # E, M, 4 angles
N_FEATURES = 10  # E_n, logM_n, sin 2a (4), cos 2a (4)
N_ANGLES = 4
#: Largest kurtosis of n = 256 spectral values (n - 2 + 1/(n - 1)); a bound for predictions.
MAX_KURTOSIS = 254.004


@dataclass(frozen=True)
class Normalizer:
    """Standardization of E and log M (means and standard deviations)."""

    e_mean: float = 3.0
    """Mean of E (L2 norm of the field)."""
    e_std: float = 1.0
    """Standard deviation of E (> 0)."""
    logm_mean: float = 3.5
    """Mean of log M (spectral kurtosis)."""
    logm_std: float = 0.5
    """Standard deviation of log M (> 0)."""

    def __post_init__(self) -> None:
        checks.finite(self, 'e_mean', 'logm_mean')
        checks.positive(self, 'e_std', 'logm_std')

    @classmethod
    def fit(cls, energy_norm: np.ndarray, kurtosis: np.ndarray) -> Normalizer:
        """Statistics of E (L2 norm) and M samples (any shape)."""
        e = np.asarray(energy_norm, float).ravel()
        logm = np.log(np.asarray(kurtosis, float).ravel())
        return cls(float(e.mean()), float(max(e.std(), 1e-6)), float(logm.mean()),
                   float(max(logm.std(), 1e-6)))

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def states(self, energy_norm: torch.Tensor, kurtosis: torch.Tensor) -> torch.Tensor:
        """(..., 2) normalized ``(E_n, logM_n)`` from E and M of shape (...)."""
        return torch.stack([(energy_norm - self.e_mean) / self.e_std,
                            (torch.log(kurtosis) - self.logm_mean) / self.logm_std], dim=-1)

    def unstates(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """E and M (each (...)) from normalized states v (..., 2), within their physical
        ranges (E >= 0; 1 <= M <= MAX_KURTOSIS)."""
        energy_norm = (v[..., 0] * self.e_std + self.e_mean).clamp(min=0.0)
        log_m = (v[..., 1] * self.logm_std + self.logm_mean).clamp(0.0, math.log(MAX_KURTOSIS))
        kurtosis = torch.exp(log_m)
        return energy_norm, kurtosis

    def objective(self, v: torch.Tensor) -> torch.Tensor:
        """O = E / M from normalized states v (..., 2); differentiable."""
        energy_norm, kurtosis = self.unstates(v)
        return energy_norm / kurtosis


def measurements(data: dict[str, np.ndarray]) -> np.ndarray:
    """Measurements (..., 6) float32 ``(E, M, alpha[4])`` of a dataset's ``E`` (...),
    ``M`` (...) and ``alpha`` (..., 4) arrays."""
    return np.concatenate([data['E'][..., None], data['M'][..., None], data['alpha']],
                          axis=-1).astype(np.float32)


def angle_features(alpha: torch.Tensor) -> torch.Tensor:
    """(..., 8) ``[sin 2 alpha, cos 2 alpha]`` of angles (..., 4) in radians."""
    return torch.cat([torch.sin(2 * alpha), torch.cos(2 * alpha)], dim=-1)


def features(measured: torch.Tensor, norm: Normalizer) -> torch.Tensor:
    """(..., 10) network features of measurements (..., 6) = (E, M, 4 angles)."""
    return torch.cat([norm.states(measured[..., 0], measured[..., 1]),
                      angle_features(measured[..., 2:6])], dim=-1)


def angles_from_features(feat: torch.Tensor) -> torch.Tensor:
    """Angles in [-pi/2, pi/2) (..., 4) from (possibly unnormalized) (..., 8) sin/cos 2a."""
    return 0.5 * torch.atan2(feat[..., :N_ANGLES], feat[..., N_ANGLES:2 * N_ANGLES])
