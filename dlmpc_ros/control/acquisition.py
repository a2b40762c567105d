"""Lock acquisition for the DL-MPC: what to do while the laser is not mode-locked.

Off a pulse the measurement says little about K, so the surrogate and map are no guide. The
laser is locked while O = E/M is at the lock threshold and at ``RELOCK_FRACTION`` of its own
recent best (decaying by ``LEVEL_DECAY`` per period). After ``patience`` unlocked periods
(``relock_patience`` once locked) the supervisor scans the points of a :class:`ScanSource`
(the tracking curve and its twin, :class:`~dlmpc_ros.control.tracking.CurveScan`; without a
curve, :class:`~dlmpc_ros.control.paper_loops.MapScan`) until O locks, then hands back to
the modes, told where (:attr:`LockSupervisor.locked_at`).
Where a point's field has died, the scan seeds it: it turns the half-wave plate on through
its period at the servos' speed; a strong CW field builds on the way and forms a pulse back
at the point's setting (an NPR laser started by hand; ``bench/results/scan_sweep.md``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from dlmpc_ros.control.dlmpc_config import AcquisitionConfig
from dlmpc_ros.control.step import AngleLimits, into_range
from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.symmetry import HALF_WAVE, QUARTER_TURN


#: Largest angle gap [rad] at which the servos count as arrived at a scan point.
ARRIVE_TOLERANCE = 1e-3
#: Periods after which a scan point counts as reached anyway (a point outside the limits).
TRAVEL_PERIODS = 20
#: Also unlocked: O under this fraction of the laser's own recent best.
RELOCK_FRACTION = 0.6
#: Per-period decay of that recent best.
LEVEL_DECAY = 0.9995
#: The recent best is of the median O of this many latest periods (skips a forming pulse's spike).
LEVEL_WINDOW = 3
#: Room [rad] the scan leaves each servo from its range's ends (for the tracker's turns).
TURN_ROOM = 2.0
#: Curve parameters u (K units) the scan visits, each with its twin: from the end of the
#: tracker's reach inward (there the better branch locks at any K, ``scan_from_reach.md``).
CURVE_POINTS = (-0.4, -0.35, -0.3, -0.25, -0.2, -0.15, -0.1, -0.05, 0.0)
#: A point's field is dead under this fraction of the latest locked period's E (dead points
#: read 0.07-0.18 of it in development traces, others >= 0.5; ``scan_sweep.md``).
WEAK_FIELD = 0.25


@dataclass(frozen=True)
class ScanPoint:
    """A candidate angle set of the scan."""

    angles: np.ndarray = field(repr=False)
    """(4,) angles [rad]."""
    branch: int = 0
    """The tracking curve's branch it lies on (1: the curve, -1: its twin; 0: none)."""
    estimate: float = float('nan')
    """Its curve parameter on the tracker's estimate axis (K units; NaN: none)."""


class ScanSource(Protocol):
    """Where the scan goes."""

    def pass_order(self, current: np.ndarray) -> list[ScanPoint]:
        """The points of a new pass, in order, from the angles (4,) [rad] ``current``."""

    def note_locked(self, surrogate: float) -> None:
        """A locked period, with the estimator's surrogate for it (NaN: none)."""


class LockSupervisor:
    """Per period: None while the DL-MPC loops are in charge, else the scan's angles (4,) [rad].

    ``threshold``: O (E/M units) at and above which the laser is locked; ``limits``: the
    servos' :class:`AngleLimits` (None: no ``TURN_ROOM`` kept). :attr:`locked_at`: the
    scan's point in the period O locked (else None)."""

    def __init__(self, threshold: float, source: ScanSource,
                 config: AcquisitionConfig | None = None,
                 limits: AngleLimits | None = None) -> None:
        if not threshold > 0:
            raise ValueError(f'lock threshold must be > 0, got {threshold}')
        self.config = config or AcquisitionConfig()
        self.threshold = float(threshold)
        self.source = source
        self.limits = limits
        self.unlocked = 0
        self.was_locked = False  # whether the laser has been locked in this run
        self.level = 0.0  # the laser's recent best O (a decaying maximum)
        self._latest: deque[float] = deque(maxlen=LEVEL_WINDOW)  # finite O
        self.locked_at: ScanPoint | None = None
        self._order: list[ScanPoint] = []
        self._target: ScanPoint | None = None
        self._dwell = self._travel = 0
        self.pulse_energy = float('nan')  # E of the latest locked period
        self._sweep_from: np.ndarray | None = None  # where the seeding sweep started
        self._swept = 0.0  # how far it has turned the half-wave plate [rad]
        #: Whether the latest command only moves the servos on (no measurement needed).
        self.travelling = False

    def locked(self, objective: float) -> bool:
        """Whether O is at the lock threshold and at ``RELOCK_FRACTION`` of the level."""
        threshold = max(self.threshold, RELOCK_FRACTION * self.level)
        return bool(np.isfinite(objective) and objective >= threshold)

    def step(self, objective: float, current: np.ndarray, surrogate: float,
             energy: float = float('nan')) -> np.ndarray | None:
        """Measured O, the angles (4,) [rad], the surrogate and the measured E (NaN: none)
        -> the scan's angles for the next period, or None."""
        self.locked_at = None
        self.travelling = False
        if np.isfinite(objective):
            self._latest.append(float(objective))
            self.level = max(float(np.median(self._latest)), self.level * LEVEL_DECAY)
        locked = self.locked(objective)
        if locked:
            if np.isfinite(energy):
                self.pulse_energy = float(energy)
            self.was_locked = True
            self.source.note_locked(surrogate)
            self.locked_at = self._target
            self.unlocked = 0
            self._order, self._target = [], None
            return None
        self.unlocked += 1
        cfg = self.config
        if self.unlocked <= (cfg.relock_patience if self.was_locked else cfg.patience):
            return None
        return self._scan(np.asarray(current, float), float(energy))

    def _toward(self, current: np.ndarray) -> np.ndarray:
        """The command (4,) [rad] toward the scan's point: the point, or where its nearest
        pi-equivalent is outside the limits less ``TURN_ROOM``, a step <= pi/4 into them."""
        angles = self._target.angles
        if self.limits is None:
            return angles
        low, high = self.limits.low + TURN_ROOM, self.limits.high - TURN_ROOM
        if high - low < np.pi:  # too narrow a range to choose
            return angles
        nearest = angles + np.pi * np.round((current - angles) / np.pi)
        if np.all((nearest >= low) & (nearest <= high)):
            return angles  # the servo limits take that equivalent themselves
        goal = into_range(nearest, low, high)
        return current + np.clip(goal - current, -np.pi / 4, np.pi / 4)

    def _arrived(self, current: np.ndarray) -> bool:
        """Whether the servos are at the scan's point (or have travelled long enough)."""
        gap = wrap_angles(current - self._target.angles)  # pi-periodic
        return float(np.max(np.abs(gap))) <= ARRIVE_TOLERANCE or self._travel >= TRAVEL_PERIODS

    def _swept_angles(self) -> np.ndarray:
        """The seeding sweep's command (4,) [rad]: its start, the half-wave plate turned on."""
        angles = self._sweep_from.copy()
        angles[HALF_WAVE] += self._swept
        return angles

    def _scan(self, current: np.ndarray, energy: float) -> np.ndarray:
        if self._target is not None:
            self._travel += 1
            if self._sweep_from is None and not self._arrived(current):
                self.travelling = True
                return self._toward(current)
            if self._dwell >= 1 and self._sweep_from is None \
                    and energy < WEAK_FIELD * self.pulse_energy:  # the field died
                self._sweep_from, self._dwell = current.copy(), 0
            if self._sweep_from is not None and self._swept < QUARTER_TURN:
                step = (self.limits or AngleLimits()).max_step
                self._swept = min(self._swept + step, QUARTER_TURN)
                return self._swept_angles()
            self._dwell += 1
            if self._dwell < self.config.dwell_periods:
                return self._toward(current) if self._sweep_from is None \
                    else self._swept_angles()
        if not self._order:
            self._order = self.source.pass_order(current)
        self._target = self._order.pop(0)
        self._sweep_from, self._swept = None, 0.0
        self._dwell = self._travel = 0
        self.travelling = not self._arrived(current)
        return self._toward(current)
