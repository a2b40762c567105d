"""Baseline controllers: what a lab would use instead of DL-MPC (no torch, no rclpy).

- :class:`PassiveController`: the angles tuned once for the initial K, then left alone
  (the paper's comparison);
- :class:`FixedBestController`: the one angle set with the best worst-case O over the
  whole K range (what a careful engineer sets by hand);
- :class:`OracleController`: evaluation only; reads the true K and applies the oracle
  envelope's angles.

Extremum-seeking control is in :mod:`dlmpc_ros.control.esc`.
"""

from __future__ import annotations

import time

import numpy as np

from dlmpc_ros.control.step import AngleLimits, ControlStep


class _HoldAngles:
    """Commands a fixed angle set every period (the servos move there at their speed)."""

    name = 'fixed'

    def __init__(self, angles: np.ndarray, limits: AngleLimits | None = None) -> None:
        angles = np.asarray(angles, float)
        if angles.shape != (4,) or not np.isfinite(angles).all():
            raise ValueError(f'{self.name}: angles must be 4 finite numbers [rad], got {angles}')
        self.angles = angles
        self.limits = limits or AngleLimits()

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        started = time.perf_counter()
        angles = self.limits.apply(np.asarray(measurement, float)[2:6], self.angles)
        return ControlStep(angles=angles, mode=self.name,
                           latency_ms=1e3 * (time.perf_counter() - started))


class PassiveController(_HoldAngles):
    """Holds the angles that were best for the initial K (given by whoever set it up)."""

    name = 'passive'


class FixedBestController(_HoldAngles):
    """Holds the angle set with the best worst-case objective over the K range."""

    name = 'fixed_best'


class OracleController:
    """Applies the envelope's best angles for the true K (evaluation only).

    Parameters
    ----------
    k_grid, angles
        The oracle envelope: K values (n,) and their best angles (n, 4) [rad].
    """

    name = 'oracle'

    def __init__(self, k_grid: np.ndarray, angles: np.ndarray,
                 limits: AngleLimits | None = None) -> None:
        self.k_grid = np.asarray(k_grid, float)
        self.table = np.asarray(angles, float)
        if self.k_grid.ndim != 1 or self.table.shape != (self.k_grid.size, 4):
            raise ValueError('oracle: need K (n,) and angles (n, 4)')
        self.limits = limits or AngleLimits()
        self.true_k: float | None = None

    def observe_truth(self, k: float) -> None:
        """The true K of the latest round trip (from the simulator, never from hardware)."""
        self.true_k = float(k)

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        started = time.perf_counter()
        current = np.asarray(measurement, float)[2:6]
        if self.true_k is None:
            wanted = current
        else:
            wanted = self.table[np.abs(self.k_grid - self.true_k).argmin()]
        return ControlStep(angles=self.limits.apply(current, wanted), mode='oracle',
                           latency_ms=1e3 * (time.perf_counter() - started))
