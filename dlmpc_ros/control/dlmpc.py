"""The DL-MPC controller (paper section 3D): a supervisor over its modes.

Each control period it takes the period's measurement ``(E, M, alpha[4])``
(:mod:`~dlmpc_ros.control.period_measurement`) and the VAE's K surrogate for it, asks its
modes (:mod:`~dlmpc_ros.control.modes`) in priority order, and the first that decides
sets the next angles (within the servo limits):

1. ``acquire``: while O says the laser is off its pulse, scan for a lock
   (:mod:`~dlmpc_ros.control.acquisition`);
2. ``track``: once locked, follow K along the learned curve by the measured O
   (:mod:`~dlmpc_ros.control.tracking`); without a curve (``strategy:=paper``) the
   ``outer`` loop instead: MP-RNN plans of the next N angle sets by gradient ascent on
   the predicted O, the first applied, re-planned each period
   (:mod:`~dlmpc_ros.control.planner`), while its one-step forecasts are accurate;
3. ``inner``: the surrogate through the K-to-angles map;
4. ``hold``: keep the angles (no surrogate).
"""

from __future__ import annotations

import os
import time

import numpy as np
import torch

from dlmpc_ros.control.acquisition import (CURVE_POINTS, SCAN_POINTS, AcquisitionConfig,
                                           LockSupervisor, MapScan)
from dlmpc_ros.control.dlmpc_config import DLMPCConfig
from dlmpc_ros.control.rotation_planner import RotationPlanner
from dlmpc_ros.control.modes import (AcquireMode, Decision, HoldMode, InnerLoop, Mode,
                                     OuterLoop, Period, PredictionMonitor, TrackMode)
from dlmpc_ros.control.step import ControlStep, implausible
from dlmpc_ros.control.tracking import CurveScan, CurveTracker
from dlmpc_ros.learning.features import features
from dlmpc_ros.learning.kmap import KMap
from dlmpc_ros.learning.mprnn import MPRNN
from dlmpc_ros.learning.response import ResponseEnsemble


#: Per-period decay of the best measured O's score (to 0.6 of it in 1,000 periods): older
#: measurements were at another K.
BEST_DECAY = 0.9995
#: Largest angle change [rad] between two periods that still counts as the same angles.
SAME_ANGLES = 1e-3


class BestAngles:
    """The angles with the best O measured lately: each period's score decays by
    ``BEST_DECAY``; angles held for two periods score the lower O of the two (a pulse
    just formed overshoots for a period) and replace the best when they score at least
    its decayed score."""

    def __init__(self) -> None:
        self.angles: np.ndarray | None = None   # (4,) [rad]
        self.score = 0.0
        self._last: tuple[np.ndarray, float] | None = None

    def observe(self, current: np.ndarray, objective: float) -> None:
        self.score *= BEST_DECAY
        last, self._last = self._last, (np.array(current, float), float(objective))
        if last is None or not np.isfinite(objective) or not np.isfinite(last[1]) \
                or np.max(np.abs(current - last[0])) > SAME_ANGLES:
            return
        held = min(objective, last[1])
        if BEST_RESCORE and self.angles is not None \
                and np.max(np.abs(current - self.angles)) <= SAME_ANGLES:
            self.score = held  # the best angles measured again: what they give now
            return
        if held >= self.score:
            self.angles, self.score = np.array(current, float), held


class HoldBest:
    """Hold the best angles measured lately (:class:`BestAngles`; the current ones before
    any): where the laser is lost, go back to what worked rather than wander."""

    name = 'hold'

    def __init__(self, best: BestAngles) -> None:
        self.best = best

    threshold = 0.0

    def decide(self, period: Period) -> Decision | None:
        if BEST_LOCK and (self.best.angles is None or self.best.score < self.threshold):
            return None
        return Decision(period.current if self.best.angles is None else self.best.angles,
                        self.name)

    def stand_down(self) -> None:
        """Stateless."""


#: Largest |surrogate| taken as an estimate (the VAE's latent means lie within a few
#: units); a larger one, however finite, counts as no estimate.
SURROGATE_LIMIT = 1e3
BEST_LOCK = os.environ.get('DLMPC_BEST_LOCK', '0') == '1'
BEST_RESCORE = os.environ.get('DLMPC_BEST_RESCORE', '0') == '1'
BEST_RESET = os.environ.get('DLMPC_BEST_RESET', '0') == '1'
HOLD_BEST = os.environ.get('DLMPC_HOLD_BEST', '0') == '1'


class DLMPCController:
    """Stateful DL-MPC controller; one :meth:`step` per control period.

    ``target_objective``: the mean O of the map's training targets (the lock threshold is
    ``acquisition.lock_fraction`` x it; None: no scan, no tracking). ``curve``: the tracking
    curve ``(grid (n,), angles (n, 4), steady O (n,))`` (None: no tracking).
    ``rotation_prior`` and ``turn_correction``: what a calibration bag taught
    (:mod:`dlmpc_ros.training.adapt`).
    """

    name = 'dlmpc'
    #: The harnesses (fast runs, the lock benchmark, the controller nodes) give it the VAE
    #: estimator's surrogate with each measurement.
    uses_estimator = True

    def __init__(self, kmap: KMap, mprnn: MPRNN, config: DLMPCConfig | None = None,
                 target_objective: float | None = None,
                 curve: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                 response: ResponseEnsemble | None = None,
                 rotation_prior: tuple[np.ndarray, np.ndarray] | None = None,
                 turn_correction: np.ndarray | None = None) -> None:
        self.config = config or DLMPCConfig()
        self.turn_correction = turn_correction
        self.target_objective = target_objective
        self.curve = curve
        self.response = response
        self.rotation_prior = rotation_prior
        self.kmap = kmap
        self.model = mprnn
        self.model.kmap = kmap
        self.model.eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.norm = mprnn.config.normalizer
        cfg = self.config
        lock_fraction = (cfg.acquisition or AcquisitionConfig()).lock_fraction
        self.acquisition: LockSupervisor | None = None
        self.tracker: CurveTracker | None = None
        self.planner: RotationPlanner | None = None
        if target_objective is not None and curve is not None and cfg.tracking is not None:
            if response is not None and cfg.planner is not None:
                self.planner = RotationPlanner(response, cfg.planner, turn_correction)
            grid, angles, expected = curve
            self.best = BestAngles()
            self.tracker = CurveTracker(grid, angles, lock_fraction * target_objective,
                                        cfg.tracking, expected, cfg.limits, self.planner,
                                        self.best)
            if rotation_prior is not None:
                self.tracker.rotation.start_from(*rotation_prior)
        if target_objective is not None and cfg.acquisition is not None:
            source = (MapScan(self.map_angles, SCAN_POINTS) if self.tracker is None
                      else CurveScan(self.tracker, CURVE_POINTS))
            self.acquisition = LockSupervisor(lock_fraction * target_objective, source,
                                              cfg.acquisition, cfg.limits)
        # with a tracker the MP-RNN does not plan (module docstring, point 3), and nothing
        # scores its forecasts
        self.monitor: PredictionMonitor | None = None
        self.outer: OuterLoop | None = None
        if self.tracker is None:
            self.monitor = PredictionMonitor(mprnn, cfg)
            self.outer = OuterLoop(self.monitor, cfg)
        self.modes: list[Mode] = [
            *([AcquireMode(self.acquisition, self.tracker)]
              if self.acquisition is not None else []),
            TrackMode(self.tracker) if self.tracker is not None else self.outer,
            InnerLoop(self.map_angles), HoldMode()]
        if self.tracker is None:
            self.best = BestAngles()
        if self.tracker is not None and HOLD_BEST:
            hb = HoldBest(self.best)
            hb.threshold = self.tracker.threshold
            if BEST_LOCK:
                self.modes.insert(-2, hb)
            else:
                self.modes[-2:] = [hb]

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
        """Run one forward and backward pass on zeros (no state touched), so that the first
        real plan does not pay torch's one-off start-up cost in the middle of a run (nothing
        to do where the MP-RNN never plans)."""
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
            x = features(torch.as_tensor(measurement, dtype=torch.float32), self.norm)  # (10,)
            error = self.monitor.observe(x)
        period = Period(
            current=measurement[2:6],
            objective=measurement[0] / measurement[1] if measurement[1] > 0 else float('nan'),
            surrogate=float('nan') if surrogate is None else float(surrogate))
        self.best.observe(period.current, period.objective)
        decision = self._decide(period)
        if BEST_RESET and decision.mode == 'acquire':
            self.best.__init__()  # lost: what was best before may not hold now
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
