"""The DL-MPC controller (paper section 3D): a supervisor over its modes.

Each control period it takes the period's measurement ``(E, M, alpha[4])``
(:mod:`~dlmpc_ros.control.step`), asks its modes in priority order (each
with one verb: ``decide(period)`` returns a :class:`Decision` or None to pass; the modes
after the one that decides ``stand_down``), and the first that decides sets the next
angles (within the servo limits):

1. ``acquire``: while O says the laser is off its pulse, scan for a lock
   (:mod:`~dlmpc_ros.control.acquisition`);
2. ``track``: once locked, follow K along the learned curve by the measured O
   (:mod:`~dlmpc_ros.control.tracking`); without a curve (``strategy:=paper``) the paper's
   ``outer`` (MP-RNN plans) and ``inner`` (surrogate to map) loops instead
   (:mod:`~dlmpc_ros.control.paper_loops`);
3. ``hold``: keep the angles (with a curve: whenever the tracker is not in charge).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from dlmpc_ros.control.acquisition import CURVE_POINTS, LockSupervisor
from dlmpc_ros.control.dlmpc_config import AcquisitionConfig, DLMPCConfig
from dlmpc_ros.control.paper_loops import (SCAN_POINTS, InnerLoop, MapScan, OuterLoop,
                                           PredictionMonitor)
from dlmpc_ros.control.rotation_planner import RotationPlanner
from dlmpc_ros.control.step import ControlStep, Decision, Mode, Period, implausible
from dlmpc_ros.control.tracking import CurveScan, CurveTracker
from dlmpc_ros.learning.kmap import KMap
from dlmpc_ros.learning.mprnn import MPRNN
from dlmpc_ros.learning.response import ResponseEnsemble

#: Largest |surrogate| taken as an estimate (the VAE's latent means lie within a few
#: units); a larger one, however finite, counts as no estimate.
SURROGATE_LIMIT = 1e3


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
    """Keep the angles (the last resort: no surrogate)."""

    name = 'hold'

    def decide(self, period: Period) -> Decision:
        return Decision(period.current, self.name)


class DLMPCController:
    """Stateful DL-MPC controller; one :meth:`step` per control period. ``target_objective``:
    the mean O of the map's training targets (the lock threshold is ``acquisition.lock_fraction``
    x it; None: no scan, no tracking); ``curve``: the tracking curve ``(grid (n,), angles (n, 4),
    steady O (n,))`` (None: no tracking); ``rotation_prior`` and ``turn_correction``: what a
    calibration bag taught (:mod:`dlmpc_ros.training.adapt`)."""

    name = 'dlmpc'

    def __init__(self, kmap: KMap, mprnn: MPRNN, config: DLMPCConfig | None = None,
                 target_objective: float | None = None,
                 curve: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 response: ResponseEnsemble | None = None,
                 rotation_prior: tuple[np.ndarray, np.ndarray] | None = None,
                 turn_correction: np.ndarray | None = None) -> None:
        self.config = config or DLMPCConfig()
        self.target_objective, self.curve, self.response = target_objective, curve, response
        self.rotation_prior, self.turn_correction = rotation_prior, turn_correction
        self.kmap = kmap
        self.model = mprnn
        self.model.kmap = kmap
        self.model.eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        cfg = self.config
        lock_fraction = (cfg.acquisition or AcquisitionConfig()).lock_fraction
        self.acquisition: LockSupervisor | None = None
        self.tracker: CurveTracker | None = None
        self.planner: RotationPlanner | None = None
        if target_objective is not None and curve is not None and cfg.tracking is not None:
            if response is not None and cfg.planner is not None:
                self.planner = RotationPlanner(response, cfg.planner, turn_correction)
            grid, angles, expected = curve
            self.tracker = CurveTracker(grid, angles, lock_fraction * target_objective,
                                        cfg.tracking, expected, cfg.limits, self.planner)
            if rotation_prior is not None:
                self.tracker.rotation.start_from(*rotation_prior)
        if target_objective is not None and cfg.acquisition is not None:
            source = (MapScan(self.map_angles, SCAN_POINTS) if self.tracker is None
                      else CurveScan(self.tracker, CURVE_POINTS))
            self.acquisition = LockSupervisor(lock_fraction * target_objective, source,
                                              cfg.acquisition, cfg.limits)
        # with a curve (the map closed on measured O) the paper's loops do not run: no plans,
        # no surrogate, the angles hold instead (stress_ablation.md, inner_loop_hold.md)
        self.monitor: PredictionMonitor | None = None
        self.outer: OuterLoop | None = None
        if self.tracker is None:
            self.monitor = PredictionMonitor(mprnn, cfg)
            self.outer = OuterLoop(self.monitor, cfg)
        acquire = [] if self.acquisition is None else [AcquireMode(self.acquisition, self.tracker)]
        loops = ([TrackMode(self.tracker)] if self.tracker is not None
                 else [self.outer, InnerLoop(self.map_angles)])
        self.modes: list[Mode] = [*acquire, *loops, HoldMode()]
        #: Whether the harnesses and the node give it the VAE's surrogate (the paper's loops)
        self.uses_estimator = self.tracker is None

    def fresh(self) -> DLMPCController:
        """A controller with the same models and settings and no history."""
        return DLMPCController(self.kmap, self.model, self.config, self.target_objective,
                               self.curve, self.response, self.rotation_prior,
                               self.turn_correction)

    def map_angles(self, surrogate: float) -> np.ndarray:
        """The map's angles (4,) [rad] for a surrogate value."""
        with torch.no_grad():
            return self.kmap(torch.tensor([[surrogate]], dtype=torch.float32))[0].numpy()

    def warm_up(self) -> None:
        """One forward and backward pass on zeros (no state touched): the first real plan then
        does not pay torch's one-off start-up cost mid-run (only where the MP-RNN plans)."""
        if self.outer is None:
            return
        history = torch.zeros(1, self.model.min_history(), 10)  # (1, N + 2b, features)
        plan = torch.zeros(1, self.model.config.horizon, 4, requires_grad=True)
        self.model(history, plan).objective.sum().backward()

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        """Measurement (6,) and the estimator's surrogate for it -> next period's angles."""
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        if implausible(measurement) is not None:  # hold; the models never see it
            current = np.nan_to_num(measurement[2:6], nan=0.0)
            return ControlStep(angles=self.config.limits.apply(current, current), mode='hold',
                               latency_ms=1e3 * (time.perf_counter() - started))
        if surrogate is not None and not abs(surrogate) <= SURROGATE_LIMIT:
            surrogate = None  # no VAE latent is that far out: treat it as no estimate
        if self.planner is not None:
            self.planner.observe(measurement[0], measurement[1])
        error = float('nan')  # of the MP-RNN's forecast for this period
        if self.monitor is not None:
            error = self.monitor.observe(measurement)
        period = Period(
            current=measurement[2:6],
            objective=measurement[0] / measurement[1] if measurement[1] > 0 else float('nan'),
            surrogate=float('nan') if surrogate is None else float(surrogate),
            energy=float(measurement[0]))
        decision = self._decide(period)
        angles = self.config.limits.apply(period.current, decision.angles)
        if self.monitor is not None:
            self.monitor.expect(decision.predicted_next)
        reported = period.surrogate if decision.surrogate is None else decision.surrogate
        return ControlStep(angles=angles, mode=decision.mode, surrogate=reported,
                           prediction_error=error,
                           predicted_objective=decision.predicted_objective,
                           iterations=decision.iterations,
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
