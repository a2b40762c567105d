"""Lock acquisition for the DL-MPC: what to do while the laser is not mode-locked.

Off a pulse the measurement says little about K (a continuous-wave or noisy field looks
alike for every K), so the surrogate and the map are no guide, and the angles they give
may hold the laser off the pulse for ever. The supervisor watches the measured objective
O = E/M against a lock threshold (a fraction of the mean O of the map's own training
targets: no K) and, after ``patience`` unlocked periods, scans the map's curve: it visits
the angles the map gives for a fixed list of surrogate values (equal-probability
quantiles of the VAE prior, nearest to the last surrogate seen while locked first),
dwelling ``dwell_periods`` at each once the servos are there, until O passes the
threshold. Then control goes back to the DL-MPC loops.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from dlmpc_ros.core import checks
from dlmpc_ros.core.angles import wrap_angles


@dataclass(frozen=True)
class AcquisitionConfig:
    """Settings of the lock supervisor (times in control periods, angles in radians)."""

    lock_fraction: float = 0.5
    """Locked when O >= lock_fraction x the mean O of the map's training targets."""
    patience: int = 10
    """Unlocked periods before the scan starts (the loops may still be acquiring)."""
    dwell_periods: int = 5
    """Periods the scan waits at each point once the servos are there."""
    scan_points: int = 9
    """Surrogate values scanned (equal-probability quantiles of the VAE prior)."""
    arrive_tolerance: float = 1e-3
    """Largest angle gap [rad] at which the servos count as arrived at a scan point."""
    travel_periods: int = 20
    """Periods after which a scan point counts as reached even if the servos are not
    there (a point outside the angle limits)."""

    def __post_init__(self) -> None:
        if not 0 < self.lock_fraction < 1:
            raise ValueError(f'lock_fraction must be in (0, 1), got {self.lock_fraction}')
        if min(self.patience, self.dwell_periods, self.scan_points, self.travel_periods) < 1:
            raise ValueError('patience, dwell_periods, scan_points and travel_periods must '
                             'be >= 1')
        checks.positive(self, 'arrive_tolerance')


def scan_surrogates(points: int) -> np.ndarray:
    """(points,) surrogate values to scan: equal-probability quantiles of N(0, 1), the
    VAE prior of the latent coordinate the surrogate is."""
    normal = NormalDist()
    return np.array([normal.inv_cdf((i + 0.5) / points) for i in range(points)])


class LockSupervisor:
    """Per control period: None while the DL-MPC loops are in charge, else the angles
    (4,) [rad] of the scan.

    ``threshold`` is the objective O (E/M units) at and above which the laser counts as
    locked; ``map_angles`` gives the map's angles (4,) for a surrogate value."""

    def __init__(self, threshold: float, map_angles: Callable[[float], np.ndarray],
                 config: AcquisitionConfig | None = None) -> None:
        if not threshold > 0:
            raise ValueError(f'lock threshold must be > 0, got {threshold}')
        self.config = config or AcquisitionConfig()
        self.threshold = float(threshold)
        self.map_angles = map_angles
        self.surrogates = scan_surrogates(self.config.scan_points)
        self.last_surrogate = 0.0
        self.unlocked = 0
        self._order: list[int] = []
        self._target: np.ndarray | None = None
        self._dwell = self._travel = 0

    def locked(self, objective: float) -> bool:
        return bool(np.isfinite(objective) and objective >= self.threshold)

    def step(self, objective: float, current: np.ndarray, surrogate: float) -> np.ndarray | None:
        if self.locked(objective):
            if np.isfinite(surrogate):
                self.last_surrogate = float(surrogate)
            self.unlocked = 0
            self._order, self._target = [], None
            return None
        self.unlocked += 1
        if self.unlocked <= self.config.patience:
            return None
        return self._scan(np.asarray(current, float))

    def _scan(self, current: np.ndarray) -> np.ndarray:
        if self._target is not None:
            self._travel += 1
            gap = wrap_angles(current - self._target)  # pi-periodic
            there = (np.max(np.abs(gap)) <= self.config.arrive_tolerance
                     or self._travel >= self.config.travel_periods)
            if not there:
                return self._target
            self._dwell += 1
            if self._dwell < self.config.dwell_periods:
                return self._target
        if not self._order:  # a new pass, nearest to the last surrogate seen while locked
            self._order = [int(i) for i in
                           np.argsort(np.abs(self.surrogates - self.last_surrogate))]
        index = self._order.pop(0)
        self._target = np.asarray(self.map_angles(float(self.surrogates[index])), float)
        self._dwell = self._travel = 0
        return self._target
