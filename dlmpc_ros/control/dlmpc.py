"""The DL-MPC controller (paper section 3D): a :class:`Supervisor` asks its modes
(:class:`~dlmpc_ros.control.step.Mode`) in priority order each control period, and the first
that decides sets the next angles. The default strategy (:class:`DLMPCController`): acquire
(scan the curve and its twin for a lock, :class:`LockSupervisor`), track (follow K along the
curve, turning it where the predictor expects more O, :mod:`~dlmpc_ros.control.tracking`),
hold. The paper's loops are the same supervisor with other modes (``paper_loops``).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from dlmpc_ros.control.dlmpc_config import AcquisitionConfig, DLMPCConfig
from dlmpc_ros.control.rotation_planner import RotationPlanner
from dlmpc_ros.control.step import (AngleLimits, ControlStep, Decision, Mode, Period,
                                    implausible, into_range)
from dlmpc_ros.control.tracking import CurveTracker
from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.symmetry import HALF_WAVE, QUARTER_TURN

if TYPE_CHECKING:  # torch-based: the caller loads it
    from dlmpc_ros.learning.response import ResponseEnsemble

#: Largest |surrogate| taken as an estimate (the VAE's latent means lie within a few
#: units); a larger one, however finite, counts as no estimate.
SURROGATE_LIMIT = 1e3


class Supervisor:
    """Modes in priority order (:attr:`modes`), one :meth:`step` per control period; a
    subclass may read each plausible measurement first (:meth:`observe`), the decision after."""

    name = 'dlmpc'
    #: Whether the harnesses and the node give it the VAE's surrogate (the paper's loops).
    uses_estimator = False

    def __init__(self, config: DLMPCConfig, modes: list[Mode]) -> None:
        self.config, self.modes = config, modes

    def observe(self, measurement: np.ndarray) -> float:
        """A plausible measurement (6,) before the modes decide -> its forecast's error (NaN)."""
        return float('nan')

    def decided(self, decision: Decision) -> None:
        """The period's decision (after the modes)."""

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        """Measurement (6,) and the estimator's surrogate for it -> next period's angles."""
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        if implausible(measurement):  # hold; the models never see it
            current = np.nan_to_num(measurement[2:6], nan=0.0)
            return ControlStep(angles=self.config.limits.apply(current, current), mode='hold',
                               latency_ms=1e3 * (time.perf_counter() - started))
        if surrogate is not None and not abs(surrogate) <= SURROGATE_LIMIT:
            surrogate = None  # no VAE latent is that far out: treat it as no estimate
        error = self.observe(measurement)
        period = Period(
            current=measurement[2:6],
            objective=measurement[0] / measurement[1] if measurement[1] > 0 else float('nan'),
            surrogate=float('nan') if surrogate is None else float(surrogate),
            energy=float(measurement[0]))
        decision = self._decide(period)
        angles = self.config.limits.apply(period.current, decision.angles)
        self.decided(decision)
        reported = period.surrogate if decision.surrogate is None else decision.surrogate
        return ControlStep(angles=angles, mode=decision.mode, surrogate=reported,
                           prediction_error=error, iterations=decision.iterations,
                           predicted_objective=decision.predicted_objective,
                           latency_ms=1e3 * (time.perf_counter() - started),
                           measure=not decision.travel)

    def _decide(self, period: Period) -> Decision:
        """The first mode's decision; the modes after it stand down."""
        for i, mode in enumerate(self.modes):
            decision = mode.decide(period)
            if decision is not None:
                for later in self.modes[i + 1:]:
                    later.stand_down()
                return decision
        raise AssertionError('HoldMode always decides')  # pragma: no cover


class AcquireMode(Mode):
    """Scan for a pulse while unlocked; the tracker (if any) enters where the scan locks."""

    name = 'acquire'

    def __init__(self, supervisor: LockSupervisor, tracker: CurveTracker | None = None) -> None:
        self.supervisor, self.tracker = supervisor, tracker

    def decide(self, period: Period) -> Decision | None:
        scan = self.supervisor.step(period.objective, period.current, period.surrogate,
                                    period.energy)
        if scan is not None:
            return Decision(scan, self.name, travel=self.supervisor.travelling)
        point = self.supervisor.locked_at
        if point is not None and point.branch and self.tracker is not None:
            self.tracker.enter_at(point.estimate, point.branch, period.objective, period.current)
        return None


class TrackMode(Mode):
    """Hold the laser on the tracking curve and follow K along it by the measured O."""

    name = 'track'

    def __init__(self, tracker: CurveTracker) -> None:
        self.tracker = tracker

    def decide(self, period: Period) -> Decision | None:
        on_curve = self.tracker.step(period.objective, period.current)
        if on_curve is None:
            return None
        return Decision(on_curve, 'plan' if self.tracker.planned else self.name,
                        surrogate=self.tracker.estimate)

    def stand_down(self) -> None:
        self.tracker.interrupt()


class HoldMode(Mode):
    """Keep the angles (the last resort)."""

    name = 'hold'

    def decide(self, period: Period) -> Decision:
        return Decision(period.current, self.name)


class DLMPCController(Supervisor):
    """The default strategy: acquire, track (and plan), hold. Locked at ``lock_fraction`` x
    ``target_objective``; ``curve``: ``(grid (n,), angles (n, 4), steady O (n,))``; ``response``:
    the predictor (None: no planner); ``rotation_prior``, ``turn_correction``: a calibration's."""

    def __init__(self, config: DLMPCConfig, target_objective: float,
                 curve: tuple[np.ndarray, np.ndarray, np.ndarray],
                 response: ResponseEnsemble | None = None,
                 rotation_prior: tuple[np.ndarray, np.ndarray] | None = None,
                 turn_correction: np.ndarray | None = None) -> None:
        if config.tracking is None:  # (without them: the paper's loops, PaperDLMPC)
            raise ValueError('DLMPCController tracks a curve: it needs tracking settings')
        self.target_objective, self.curve, self.response = target_objective, curve, response
        self.rotation_prior, self.turn_correction = rotation_prior, turn_correction
        threshold = (config.acquisition or AcquisitionConfig()).lock_fraction * target_objective
        self.planner: RotationPlanner | None = None
        if response is not None and config.planner is not None:
            self.planner = RotationPlanner(response, config.planner, turn_correction)
        grid, angles, expected = curve
        self.tracker = CurveTracker(grid, angles, threshold, config.tracking, expected,
                                    config.limits, self.planner)
        if rotation_prior is not None:
            self.tracker.rotation.start_from(*rotation_prior)
        self.acquisition: LockSupervisor | None = None
        if config.acquisition is not None:
            self.acquisition = LockSupervisor(threshold, CurveScan(self.tracker, CURVE_POINTS),
                                              config.acquisition, config.limits)
        acquire = [] if self.acquisition is None else [AcquireMode(self.acquisition, self.tracker)]
        super().__init__(config, [*acquire, TrackMode(self.tracker), HoldMode()])

    def fresh(self) -> DLMPCController:
        """A controller with the same models and settings and no history."""
        return DLMPCController(self.config, self.target_objective, self.curve, self.response,
                               self.rotation_prior, self.turn_correction)

    def observe(self, measurement: np.ndarray) -> float:
        if self.planner is not None:
            self.planner.observe(measurement[0], measurement[1])
        return float('nan')


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

    angles: np.ndarray = field(repr=False)  # (4,) [rad]
    branch: int = 0  # the curve's branch it lies on (1: the curve, -1: its twin; 0: none)
    estimate: float = float('nan')  # its parameter on the tracker's estimate axis (K units)


class ScanSource(Protocol):
    """Where the scan goes: the points of a new pass, in order, from the ``current`` angles
    (4,) [rad]; told of each locked period with the estimator's surrogate (NaN: none)."""

    def pass_order(self, current: np.ndarray) -> list[ScanPoint]: ...

    def note_locked(self, surrogate: float) -> None: ...


class LockSupervisor:
    """Per period: None while the laser is locked (:meth:`locked`), else after ``patience``
    unlocked periods (``relock_patience`` once locked) the angles (4,) [rad] of a scan over a
    :class:`ScanSource`'s points (:attr:`locked_at`: where it locked). Where a point's field
    died it turns the half-wave plate on through its period: a CW field builds and forms a
    pulse at the point's setting (as by hand). ``limits`` None: no ``TURN_ROOM`` kept."""

    def __init__(self, threshold: float, source: ScanSource,
                 config: AcquisitionConfig | None = None,
                 limits: AngleLimits | None = None) -> None:
        if not threshold > 0:
            raise ValueError(f'lock threshold must be > 0, got {threshold}')
        self.config, self.threshold = config or AcquisitionConfig(), float(threshold)
        self.source, self.limits, self.unlocked = source, limits, 0
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
        """Whether O is at the lock threshold and at ``RELOCK_FRACTION`` of the recent best."""
        threshold = max(self.threshold, RELOCK_FRACTION * self.level)
        return bool(np.isfinite(objective) and objective >= threshold)

    def step(self, objective: float, current: np.ndarray, surrogate: float,
             energy: float = float('nan')) -> np.ndarray | None:
        """Measured O, angles (4,) [rad], surrogate and E -> the scan's next angles, or None."""
        self.locked_at, self.travelling = None, False
        if np.isfinite(objective):
            self._latest.append(float(objective))
            self.level = max(float(np.median(self._latest)), self.level * LEVEL_DECAY)
        if self.locked(objective):
            if np.isfinite(energy):
                self.pulse_energy = float(energy)
            self.source.note_locked(surrogate)
            self.was_locked, self.locked_at, self.unlocked = True, self._target, 0
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


class CurveScan:
    """The acquisition scan over the tracking curve (a :class:`ScanSource`): for each
    parameter ``u`` of ``points``, the curve's point and its mirror twin (estimate ``-u``),
    the one nearer the current angles first. The tracker enters where the scan locks."""

    def __init__(self, tracker: CurveTracker, points: tuple[float, ...]) -> None:
        self.tracker = tracker
        self.points = tuple(float(u) for u in points)

    def pass_order(self, current: np.ndarray) -> list[ScanPoint]:
        order = []
        for u in self.points:
            on_curve = self.tracker.on_curve(u)
            pair = [ScanPoint(on_curve, 1, u), ScanPoint(on_curve + QUARTER_TURN, -1, -u)]
            pair.sort(key=lambda p: float(np.max(np.abs(wrap_angles(p.angles - current)))))
            order += pair
        return order

    def note_locked(self, surrogate: float) -> None:
        """The curve scan does not use the surrogate."""
