"""The DL-MPC controller (paper section 3D): MP-RNN planning with a VAE + map inner loop.

Each control period it receives the latest measurement ``(E, M, alpha[4])`` and returns
the angles for the next period:

- inner loop (while the history is shorter than the MP-RNN needs, and whenever the
  predictor's recent one-step error passes ``error_threshold``): the estimator's K
  surrogate of the latest measurement (the VAE, run by the caller: the estimator node or
  :class:`~dlmpc_ros.control.estimator.SurrogateEstimator`) goes through the K-to-angles
  map; with no surrogate (a silent estimator) the angles are held (mode ``hold``);
- outer loop: the MP-RNN predicts the next N states for a plan of N future angle sets,
  seeded by the previous plan (or by the map through the predicted K), and the plan is
  improved by gradient ascent on the summed predicted objective. The number of ascent
  iterations grows by one after an accurate prediction and shrinks after a poor one.
  The first planned angles are applied (receding horizon), or the whole plan over N
  periods (``apply_all``, as in the paper).

The predictor is scored only while it plans, so by default the outer loop, once its error
has passed the threshold, stays off (the shipped setting: re-arming it costs objective in
closed loop, ``bench/results/outer_loop.md``). ``monitor_prediction`` keeps scoring it in
every mode so that it can take over again; ``trust_radius`` bounds how far a plan may move
from the current angles, and ``objective_guard`` hands back to the inner loop when the
measured O under the outer loop falls.

While the measured O says the laser is off its pulse, a lock supervisor
(:mod:`~dlmpc_ros.control.acquisition`) scans the map's curve until it locks (mode
``acquire``). Once it is locked, the curve tracker (:mod:`~dlmpc_ros.control.tracking`,
mode ``track``, on by default) moves it onto the best branch-continuous angle curve and
follows K along it by extremum seeking on the measured O; the loops above run only while
it is not tracking (measured in ``bench/results/tracking.md``: the outer loop's plans
lose objective, the tracker gains it). Angle limits and a maximum step per period
(servo speed) are enforced on every command.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import torch

from dlmpc_ros.control.acquisition import AcquisitionConfig, LockSupervisor
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.control.step import ControlStep
from dlmpc_ros.control.tracking import CurveTracker, TrackingConfig
from dlmpc_ros.learning.features import features
from dlmpc_ros.learning.kmap import KMap
from dlmpc_ros.learning.mprnn import MPRNN


@dataclass(frozen=True)
class DLMPCConfig:
    """Settings of the controller (angles in radians)."""

    limits: AngleLimits = field(default_factory=AngleLimits)
    min_iterations: int = 1
    max_iterations: int = 8
    start_iterations: int = 3
    learning_rate: float = 0.05
    error_threshold: float = 1.0
    """One-step prediction error (normalized state units, averaged over recent periods)
    above which the inner loop takes over."""
    accurate_error: float = 0.3
    """Errors below this count as accurate (iterations grow)."""
    error_memory: int = 3
    apply_all: bool = False
    monitor_prediction: bool = False
    """Score the predictor's one-step forecast in every mode, not only in the outer loop,
    so that the outer loop can take over again after a spell of poor predictions."""
    trust_radius: float | None = None
    """Largest distance [rad] of a planned angle from the current angle (None: no limit);
    keeps the plan where the predictor was trained, instead of where it is wrong."""
    objective_guard: float | None = None
    """If set: when the measured O under the outer loop falls below this fraction of the O
    last measured under the inner loop, go back to the inner loop for ``guard_cooldown``
    periods (the predictor's plans are trusted only while they do not lose objective)."""
    guard_cooldown: int = 50
    acquisition: AcquisitionConfig | None = field(default_factory=AcquisitionConfig)
    """The lock acquisition scan (None: off)."""
    tracking: TrackingConfig | None = field(default_factory=TrackingConfig)
    """Curve tracking once locked (None: off; also off without a tracking curve)."""

    def __post_init__(self) -> None:
        if not 1 <= self.min_iterations <= self.start_iterations <= self.max_iterations:
            raise ValueError('need 1 <= min_iterations <= start_iterations <= max_iterations')
        if not (self.learning_rate > 0 and self.error_threshold > 0 and self.accurate_error > 0):
            raise ValueError('learning_rate, error_threshold and accurate_error must be > 0')
        if self.trust_radius is not None and not self.trust_radius > 0:
            raise ValueError('trust_radius must be > 0 (or None)')
        if self.objective_guard is not None and not 0 < self.objective_guard <= 1:
            raise ValueError('objective_guard must be in (0, 1] (or None)')
        if self.guard_cooldown < 1:
            raise ValueError('guard_cooldown must be >= 1')


class DLMPCController:
    """Stateful DL-MPC controller; one :meth:`step` per control period."""

    name = 'dlmpc'

    def __init__(self, kmap: KMap, mprnn: MPRNN, config: DLMPCConfig | None = None,
                 target_objective: float | None = None,
                 curve: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        """``target_objective`` is the mean O of the map's training targets (the map
        file's ``subset_mean_O``); the lock threshold of the acquisition scan is
        ``config.acquisition.lock_fraction`` times it. Without it (or with
        ``config.acquisition`` None) there is no acquisition scan. ``curve`` is the
        tracking curve ``(grid (n,), angles (n, 4), steady O (n,))`` of the
        ``track_curve.npz`` model file; without it, without ``target_objective`` or with
        ``config.tracking`` None, there is no curve tracking."""
        self.config = config or DLMPCConfig()
        self.target_objective = target_objective
        self.curve = curve
        self.acquisition = None
        self.tracker = None
        if target_objective is not None and self.config.acquisition is not None:
            self.acquisition = LockSupervisor(
                self.config.acquisition.lock_fraction * target_objective, self.map_angles,
                self.config.acquisition)
        if target_objective is not None and curve is not None \
                and self.config.tracking is not None:
            lock_fraction = (self.config.acquisition or AcquisitionConfig()).lock_fraction
            grid, angles, expected = curve
            self.tracker = CurveTracker(grid, angles, lock_fraction * target_objective,
                                        self.config.tracking, expected)
        self.kmap = kmap
        self.model = mprnn
        self.model.kmap = kmap
        self.model.eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.norm = mprnn.config.normalizer
        self.history: deque[torch.Tensor] = deque(maxlen=mprnn.min_history())
        self.iterations = self.config.start_iterations
        self.errors: deque[float] = deque(maxlen=self.config.error_memory)
        self._predicted_next: torch.Tensor | None = None   # (2,) v predicted for this step
        self._plan: torch.Tensor | None = None             # (N, 4) remaining plan
        self._queued: list[np.ndarray] = []                # apply_all: plan to play out
        self._last_mode = ''                               # mode of the previous step
        self._inner_objective: float | None = None         # O last measured after 'inner'
        self._blocked = 0                                  # periods the guard still blocks

    def fresh(self) -> DLMPCController:
        """A controller with the same models and settings and no history."""
        return DLMPCController(self.kmap, self.model, self.config, self.target_objective,
                               self.curve)

    def map_angles(self, surrogate: float) -> np.ndarray:
        """The map's angles (4,) [rad] for a surrogate value."""
        with torch.no_grad():
            return self.kmap(torch.tensor([[surrogate]], dtype=torch.float32))[0].numpy()

    def warm_up(self) -> None:
        """Run one forward and backward pass on zeros (no state touched), so that the first
        real plan does not pay torch's one-off start-up cost in the middle of a run."""
        history = torch.zeros(1, self.model.min_history(), 10)  # (1, N + 2b, features)
        plan = torch.zeros(1, self.model.config.horizon, 4, requires_grad=True)
        self.model(history, plan).objective.sum().backward()

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        """Measurement (6,) and the estimator's surrogate for it -> next period's angles."""
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        current = measurement[2:6]
        x = features(torch.as_tensor(measurement, dtype=torch.float32), self.norm)  # (10,)
        self.history.append(x)
        error = float('nan')
        if self._predicted_next is not None:
            error = float(torch.sqrt(((self._predicted_next - x[:2]) ** 2).mean()))
            self.errors.append(error)
            cfg = self.config
            if error < cfg.accurate_error:
                self.iterations = min(cfg.max_iterations, self.iterations + 1)
            else:
                self.iterations = max(cfg.min_iterations, self.iterations - 1)
        surrogate = float('nan') if surrogate is None else float(surrogate)
        recent = float(np.mean(self.errors)) if self.errors else 0.0
        full = len(self.history) == self.history.maxlen
        objective = measurement[0] / measurement[1] if measurement[1] > 0 else float('nan')
        if self.acquisition is not None:
            scan = self.acquisition.step(objective, current, surrogate)
            if scan is not None:
                self._drop_plan()
                if self.tracker is not None:
                    self.tracker.interrupt()
                return self._finish(current, scan, 'acquire', surrogate, error, np.array([]),
                                    0, started, None)
        if self.tracker is not None:
            on_curve = self.tracker.step(objective)
            if on_curve is not None:
                self._drop_plan()
                return self._finish(current, on_curve, 'track', self.tracker.estimate, error,
                                    np.array([]), 0, started, None)
        blocked = self._guard(objective)
        if self._queued and recent <= self.config.error_threshold and not blocked:
            wanted = self._queued.pop(0)
            return self._finish(current, wanted, 'outer', surrogate, error, np.array([]), 0,
                                started, None)
        if not full or recent > self.config.error_threshold or blocked:
            self._drop_plan()
            if not np.isfinite(surrogate):  # estimator silent: hold the angles
                return self._finish(current, current, 'hold', surrogate, error, np.array([]),
                                    0, started, None)
            return self._finish(current, self.map_angles(surrogate), 'inner', surrogate, error,
                                np.array([]), 0, started, None)
        return self._plan_outer(current, surrogate, error, started)

    def _drop_plan(self) -> None:
        """Forget the outer loop's plan and its pending prediction (another mode acts)."""
        self._plan, self._predicted_next, self._queued = None, None, []

    def _guard(self, objective: float) -> bool:
        """Update the objective guard with this period's O; True: outer loop blocked."""
        fraction = self.config.objective_guard
        if fraction is None:
            return False
        if self._blocked > 0:
            self._blocked -= 1
        if self._last_mode == 'inner' and np.isfinite(objective):
            self._inner_objective = objective
        elif (self._last_mode == 'outer' and self._inner_objective is not None
              and not objective >= fraction * self._inner_objective):
            self._blocked = self.config.guard_cooldown
        return self._blocked > 0

    def _plan_outer(self, current, surrogate, error, started) -> ControlStep:
        history = torch.stack(list(self.history))[None]                 # (1, N + 2b, 10)
        if self._plan is None:
            with torch.no_grad():
                seed = self.model(history).u[0]                         # (N, 4) from the map
        else:
            seed = torch.cat([self._plan[1:], self._plan[-1:]])         # shift the old plan
        plan = seed.clone().requires_grad_(True)
        optimizer = torch.optim.Adam([plan], lr=self.config.learning_rate)
        centre = torch.as_tensor(current, dtype=plan.dtype)
        radius = self.config.trust_radius
        for _ in range(self.iterations):
            optimizer.zero_grad()
            out = self.model(history, plan[None])
            (-out.objective.sum()).backward()
            optimizer.step()
            if radius is not None:
                with torch.no_grad():
                    plan.copy_(torch.maximum(torch.minimum(plan, centre + radius),
                                             centre - radius))
        plan = plan.detach()
        # The first control is what the servos can reach; predict with exactly that.
        plan[0] = torch.as_tensor(self.config.limits.apply(current, plan[0].numpy()),
                                  dtype=plan.dtype)
        with torch.no_grad():
            out = self.model(history, plan[None])
        self._plan = plan
        if self.config.apply_all:
            self._queued = [u.numpy() for u in plan[1:]]
        return self._finish(current, plan[0].numpy(), 'outer', surrogate, error,
                            out.objective[0].numpy(), self.iterations, started, out.v[0, 0])

    def _predict_next(self, angles: np.ndarray) -> torch.Tensor:
        """The MP-RNN's next normalized state (2,) if ``angles`` (4,) are held."""
        history = torch.stack(list(self.history))[None]                 # (1, N + 2b, 10)
        plan = torch.as_tensor(angles, dtype=torch.float32).expand(
            1, self.model.config.horizon, 4)
        with torch.no_grad():
            return self.model(history, plan).v[0, 0]

    def _finish(self, current, wanted, mode, surrogate, error, predicted, iterations, started,
                predicted_next) -> ControlStep:
        angles = self.config.limits.apply(current, wanted)
        if predicted_next is None and self.config.monitor_prediction \
                and len(self.history) == self.history.maxlen:
            # Outside the outer loop, keep scoring the predictor on what is applied, so the
            # outer loop takes over again once its predictions are accurate.
            predicted_next = self._predict_next(angles)
        self._predicted_next = predicted_next
        self._last_mode = mode
        return ControlStep(angles=angles, mode=mode, surrogate=surrogate,
                           prediction_error=error, predicted_objective=predicted,
                           iterations=iterations,
                           latency_ms=1e3 * (time.perf_counter() - started))
