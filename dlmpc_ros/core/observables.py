"""The spec's observables written directly in numpy, for checking and for measured fields.

The simulator computes the same quantities inside its compiled kernel; these plain
versions state the definitions and let hardware data or saved fields be evaluated.
"""

from __future__ import annotations

import numpy as np


def amplitude(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Real amplitude ``phi = sqrt(|u|^2 + |v|^2)``, same shape as the inputs."""
    return np.sqrt(np.abs(u) ** 2 + np.abs(v) ** 2)


def pulse_energy(phi: np.ndarray, dt: float) -> np.ndarray:
    """``integral phi^2 dt`` by the rectangle rule over the last axis."""
    return dt * np.sum(phi ** 2, axis=-1)


def spectral_kurtosis(phi: np.ndarray) -> np.ndarray:
    """Pearson kurtosis (population moments) of ``|fftshift(fft(phi))|`` over the last axis.

    A zero field has no defined kurtosis; it gets the largest possible value
    ``n - 2 + 1/(n - 1)`` (the flat-field limit), so that its objective is 0.
    """
    n = phi.shape[-1]
    s = np.abs(np.fft.fftshift(np.fft.fft(phi, axis=-1), axes=-1))
    d = s - s.mean(axis=-1, keepdims=True)
    m2 = np.mean(d ** 2, axis=-1)
    m4 = np.mean(d ** 4, axis=-1)
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(m2 > 0, m4 / np.where(m2 > 0, m2, 1.0) ** 2, n - 2 + 1 / (n - 1))


def objective_terms(u: np.ndarray, v: np.ndarray, dt: float) -> dict[str, np.ndarray]:
    """``energy``, ``E = sqrt(energy)``, ``M`` and ``O = E / M`` of fields (..., n)."""
    phi = amplitude(u, v)
    energy = pulse_energy(phi, dt)
    big_e = np.sqrt(energy)
    kurtosis = spectral_kurtosis(phi)
    return {'energy': energy, 'E': big_e, 'M': kurtosis, 'O': big_e / kurtosis}
