"""Reference integration of the cavity with scipy's DOP853, as in the authors' code.

Slow (tens of ms per round trip) but independent of the split-step solver: it integrates
the spec's Fourier-space equations as one ODE system. Used by the accuracy tests and as
the baseline of the benchmark.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.grid import Grid
from dlmpc_ros.core.jones import cavity_transfer
from dlmpc_ros.core.observables import objective_terms


def fiber_rhs(z: float, y: np.ndarray, cfg: CavityConfig, k: np.ndarray, dt: float,
              birefringence: float) -> np.ndarray:
    """d/dz of ``y = [fft(u), fft(v)]`` (2n,) complex, the spec's Fourier-space form."""
    n = k.shape[0]
    big_u, big_v = y[:n], y[n:]
    u, v = np.fft.ifft(big_u), np.fft.ifft(big_v)
    uu, vv = np.abs(u) ** 2, np.abs(v) ** 2
    energy = dt * np.sum(uu + vv)
    gain = 2 * cfg.pump / (1 + energy / cfg.saturation_energy)
    linear = gain * (1 - cfg.gain_bandwidth * k ** 2) - cfg.loss
    a, b = cfg.cross_phase, cfg.four_wave
    kerr_u = np.fft.fft((uu + a * vv) * u + b * v ** 2 * np.conj(u))
    kerr_v = np.fft.fft((a * uu + vv) * v + b * u ** 2 * np.conj(v))
    dispersion = 0.5 * cfg.dispersion * k ** 2
    return np.concatenate([
        -1j * (dispersion + birefringence) * big_u + 1j * kerr_u + linear * big_u,
        -1j * (dispersion - birefringence) * big_v + 1j * kerr_v + linear * big_v,
    ])


def reference_pass(u: np.ndarray, v: np.ndarray, birefringence: float,
                   config: CavityConfig | None = None, rtol: float = 1e-10,
                   atol: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """The fields ``(u, v)``, (n,) complex each, after one fiber pass (before the Jones
    elements), integrated with DOP853."""
    cfg = config or CavityConfig()
    grid = Grid.from_config(cfg)
    n = grid.points
    sol = solve_ivp(fiber_rhs, (0.0, cfg.fiber_length),
                    np.concatenate([np.fft.fft(u), np.fft.fft(v)]), method='DOP853',
                    rtol=rtol, atol=atol, args=(cfg, grid.k_grid, grid.dt, birefringence))
    if not sol.success:
        raise RuntimeError(f'DOP853 failed: {sol.message}')
    return np.fft.ifft(sol.y[:n, -1]), np.fft.ifft(sol.y[n:, -1])


def reference_round_trips(angles: np.ndarray, birefringence: float, round_trips: int,
                          config: CavityConfig | None = None, rtol: float = 1e-10,
                          atol: float = 1e-12, u0: np.ndarray | None = None,
                          v0: np.ndarray | None = None,
                          fields: bool = False) -> list[dict[str, float | np.ndarray]]:
    """Integrate round trips with DOP853 from ``u = v = sech(t/2)`` (or u0, v0).

    Returns one dict per round trip with ``energy, E, M, O`` after the Jones elements
    (and with ``fields``, the fields ``u`` and ``v`` there, (n,) complex).
    """
    cfg = config or CavityConfig()
    grid = Grid.from_config(cfg)
    transfer = cavity_transfer(np.asarray(angles, float))
    u = 1 / np.cosh(grid.t_grid / 2) + 0j if u0 is None else np.asarray(u0, np.complex128)
    v = u.copy() if v0 is None else np.asarray(v0, np.complex128)
    out = []
    for _ in range(round_trips):
        u, v = reference_pass(u, v, birefringence, cfg, rtol, atol)
        u, v = transfer[0, 0] * u + transfer[0, 1] * v, transfer[1, 0] * u + transfer[1, 1] * v
        row = {key: float(val) for key, val in objective_terms(u, v, grid.dt).items()}
        out.append({**row, 'u': u, 'v': v} if fields else row)
    return out
