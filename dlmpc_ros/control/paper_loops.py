"""The paper's DL-MPC (section 3D; ``strategy:=paper``, or no tracking curve):
:class:`PaperDLMPC`, the DL-MPC's supervisor (:mod:`~dlmpc_ros.control.dlmpc`) over the MP-RNN
outer loop (:class:`OuterLoop`, receding-horizon plans by :func:`solve_plan` while the
:class:`PredictionMonitor` finds its forecasts accurate), the inner loop (:class:`InnerLoop`,
the VAE's surrogate through the K-to-angles map) and hold, after the lock scan over the map's
angles (:class:`MapScan`). The default strategy runs none of them
(``bench/results/stress_ablation.md``, ``bench/results/inner_loop_hold.md``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np
import torch

from dlmpc_ros.control.dlmpc import AcquireMode, HoldMode, LockSupervisor, ScanPoint, Supervisor
from dlmpc_ros.control.dlmpc_config import ERROR_MEMORY, DLMPCConfig
from dlmpc_ros.control.step import AngleLimits, Decision, Mode, Period
from dlmpc_ros.learning.features import features
from dlmpc_ros.learning.kmap import KMap
from dlmpc_ros.learning.mprnn import MPRNN

#: Surrogate values the map scan visits (equal-probability quantiles of the VAE prior).
SCAN_POINTS = 9


@dataclass(frozen=True)
class PlanResult:
    """A solved plan."""

    first: np.ndarray  # (4,) angles for the next period [rad], one servo step from the current
    plan: torch.Tensor  # (N, 4) the whole plan [rad], its first row ``first``
    predicted_objective: np.ndarray  # (N,) the MP-RNN's O over the horizon under the plan
    predicted_next: torch.Tensor  # (2,) the normalized state predicted for the next period
    iterations: int  # Adam steps taken


def solve_plan(model: MPRNN, history: torch.Tensor, seed: torch.Tensor, current: np.ndarray,
               iterations: int, learning_rate: float, limits: AngleLimits) -> PlanResult:
    """One receding-horizon plan: improve ``seed`` (N, 4) [rad] (the previous plan shifted, or
    the map's) by ``iterations`` Adam steps of ``learning_rate`` [rad] on ``model``'s summed
    predicted O after ``history`` (1, N + 2b, 10), the recent periods' features (weights
    unchanged); then cut the first step to what the servos reach from ``current`` (4,)
    [rad] (``limits``) and predict the plan once more with it."""
    plan = seed.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([plan], lr=learning_rate)
    for _ in range(iterations):
        optimizer.zero_grad()
        out = model(history, plan[None])
        (-out.objective.sum()).backward()
        optimizer.step()
    plan = plan.detach()
    plan[0] = torch.as_tensor(limits.apply(current, plan[0].numpy()), dtype=plan.dtype)
    with torch.no_grad():
        out = model(history, plan[None])
    return PlanResult(first=plan[0].numpy().copy(), plan=plan,
                      predicted_objective=out.objective[0].numpy(),
                      predicted_next=out.v[0, 0], iterations=iterations)


class PredictionMonitor:
    """The MP-RNN's feature history and one-step accuracy: plan iterations grow by one after
    an accurate forecast (:meth:`expect`, scored by :meth:`observe`), shrink after a poor one."""

    def __init__(self, model: MPRNN, config: DLMPCConfig) -> None:
        self.model = model
        self.config = config
        self.history: deque[torch.Tensor] = deque(maxlen=model.min_history())
        self.errors: deque[float] = deque(maxlen=ERROR_MEMORY)
        self.iterations = config.start_iterations
        self._expected: torch.Tensor | None = None   # (2,) v forecast for this period

    def observe(self, measurement: np.ndarray) -> float:
        """Add the period's measurement (6,) as features (10,); return their forecast's RMS
        error (NaN: none)."""
        x = features(torch.as_tensor(measurement, dtype=torch.float32),
                     self.model.config.normalizer)
        self.history.append(x)
        if self._expected is None:
            return float('nan')
        error = float(torch.sqrt(((self._expected - x[:2]) ** 2).mean()))
        self.errors.append(error)
        cfg = self.config
        if error < cfg.accurate_error:
            self.iterations = min(cfg.max_iterations, self.iterations + 1)
        else:
            self.iterations = max(cfg.min_iterations, self.iterations - 1)
        return error

    def expect(self, v_next: torch.Tensor | None) -> None:
        """The forecast (2,) of the next period's normalized state (None: no forecast)."""
        self._expected = v_next

    @property
    def full(self) -> bool:
        """Whether the history is as long as a prediction needs."""
        return len(self.history) == self.history.maxlen

    @property
    def recent_error(self) -> float:
        """Mean of the recent forecast errors (0 before the first)."""
        return float(np.mean(self.errors)) if self.errors else 0.0

    def history_batch(self) -> torch.Tensor:
        """(1, N + 2b, 10) the history as the model's input."""
        return torch.stack(list(self.history))[None]


class OuterLoop(Mode):
    """MP-RNN planning (receding horizon); passes (dropping its plan) while the history is
    short or the recent error is over ``config.error_threshold`` (then it stays off)."""

    name = 'outer'

    def __init__(self, monitor: PredictionMonitor, config: DLMPCConfig) -> None:
        self.monitor = monitor
        self.config = config
        self.plan: torch.Tensor | None = None             # (N, 4) remaining plan

    def decide(self, period: Period) -> Decision | None:
        if not self.monitor.full or self.monitor.recent_error > self.config.error_threshold:
            self.stand_down()
            return None
        return self._solve(period)

    def stand_down(self) -> None:
        self.plan = None

    def _solve(self, period: Period) -> Decision:
        model = self.monitor.model
        history = self.monitor.history_batch()                      # (1, N + 2b, 10)
        if self.plan is None:
            with torch.no_grad():
                seed = model(history).u[0]                          # (N, 4) from the map
        else:
            seed = torch.cat([self.plan[1:], self.plan[-1:]])       # shift the old plan
        result = solve_plan(model, history, seed, period.current, self.monitor.iterations,
                            self.config.learning_rate, self.config.limits)
        self.plan = result.plan
        return Decision(result.first, self.name, predicted_objective=result.predicted_objective,
                        iterations=result.iterations, predicted_next=result.predicted_next)


class InnerLoop(Mode):
    """The estimator's surrogate through the K-to-angles map (passes without one)."""

    name = 'inner'

    def __init__(self, map_angles: Callable[[float], np.ndarray]) -> None:
        self.map_angles = map_angles

    def decide(self, period: Period) -> Decision | None:
        if not np.isfinite(period.surrogate):
            return None
        return Decision(self.map_angles(period.surrogate), self.name)


def scan_surrogates(points: int) -> np.ndarray:
    """(points,) surrogates to scan: equal-probability quantiles of N(0, 1), the VAE prior."""
    normal = NormalDist()
    return np.array([normal.inv_cdf((i + 0.5) / points) for i in range(points)])


class MapScan:
    """The map's angles at ``points`` VAE-prior quantiles, nearest the last locked first."""

    def __init__(self, map_angles: Callable[[float], np.ndarray], points: int) -> None:
        self.map_angles = map_angles
        self.surrogates = scan_surrogates(points)
        self.last_surrogate = 0.0

    def pass_order(self, current: np.ndarray) -> list[ScanPoint]:
        order = np.argsort(np.abs(self.surrogates - self.last_surrogate))
        return [ScanPoint(np.asarray(self.map_angles(float(self.surrogates[i])), float))
                for i in order]

    def note_locked(self, surrogate: float) -> None:
        if np.isfinite(surrogate):
            self.last_surrogate = float(surrogate)


class PaperDLMPC(Supervisor):
    """The paper's DL-MPC: acquire (over the map's angles), outer, inner, hold. ``kmap`` and
    ``mprnn``: the K-to-angles map and the MP-RNN; ``target_objective``: the mean O of the
    map's training targets (the lock threshold: ``acquisition.lock_fraction`` x it; None: no
    scan)."""

    uses_estimator = True

    def __init__(self, kmap: KMap, mprnn: MPRNN, config: DLMPCConfig | None = None,
                 target_objective: float | None = None) -> None:
        config = config or DLMPCConfig()
        self.kmap, self.model, self.target_objective = kmap, mprnn, target_objective
        self.model.kmap = kmap
        self.model.eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.acquisition: LockSupervisor | None = None
        if target_objective is not None and config.acquisition is not None:
            self.acquisition = LockSupervisor(config.acquisition.lock_fraction * target_objective,
                                              MapScan(self.map_angles, SCAN_POINTS),
                                              config.acquisition, config.limits)
        self.monitor = PredictionMonitor(mprnn, config)
        self.outer = OuterLoop(self.monitor, config)
        acquire = [] if self.acquisition is None else [AcquireMode(self.acquisition)]
        super().__init__(config, [*acquire, self.outer, InnerLoop(self.map_angles), HoldMode()])

    def fresh(self) -> PaperDLMPC:
        """A controller with the same models and settings and no history."""
        return PaperDLMPC(self.kmap, self.model, self.config, self.target_objective)

    def map_angles(self, surrogate: float) -> np.ndarray:
        """The map's angles (4,) [rad] for a surrogate value."""
        with torch.no_grad():
            return self.kmap(torch.tensor([[surrogate]], dtype=torch.float32))[0].numpy()

    def warm_up(self) -> None:
        """One forward and backward pass on zeros (no state touched): the first plan then does
        not pay torch's start-up cost mid-run."""
        history = torch.zeros(1, self.model.min_history(), 10)  # (1, N + 2b, features)
        plan = torch.zeros(1, self.model.config.horizon, 4, requires_grad=True)
        self.model(history, plan).objective.sum().backward()

    def observe(self, measurement: np.ndarray) -> float:
        return self.monitor.observe(measurement)

    def decided(self, decision: Decision) -> None:
        self.monitor.expect(decision.predicted_next)
