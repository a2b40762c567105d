"""The paper's outer loop (section 3D): receding-horizon plans of the MP-RNN.

:func:`solve_plan` runs gradient ascent of the MP-RNN's predicted objective over N future
angle sets; the supervisor's ``outer`` mode (:class:`~dlmpc_ros.control.dlmpc.OuterLoop`)
plans each period while the :class:`PredictionMonitor` finds the one-step forecasts
accurate; the default strategy, which tracks a curve, never plans with it
(``bench/results/stress_ablation.md``).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import torch

from dlmpc_ros.control.dlmpc_config import ERROR_MEMORY, DLMPCConfig
from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.learning.features import features
from dlmpc_ros.learning.mprnn import MPRNN


@dataclass(frozen=True)
class PlanResult:
    """A solved plan."""

    first: np.ndarray
    """(4,) angles for the next period [rad], within one servo step of the current ones."""
    plan: torch.Tensor
    """(N, 4) the whole plan [rad], its first row :attr:`first`."""
    predicted_objective: np.ndarray
    """(N,) the MP-RNN's O over the horizon under the plan."""
    predicted_next: torch.Tensor
    """(2,) the normalized state predicted for the end of the next period."""
    iterations: int
    """Adam steps taken."""


def solve_plan(model: MPRNN, history: torch.Tensor, seed: torch.Tensor, current: np.ndarray,
               iterations: int, learning_rate: float, limits: AngleLimits) -> PlanResult:
    """One receding-horizon plan: improve ``seed`` (N, 4) [rad] (the previous plan shifted,
    or the map's) by ``iterations`` Adam steps of ``learning_rate`` [rad] on ``model``'s
    summed predicted O after ``history`` (1, N + 2b, 10), the features of the recent
    periods (weights unchanged: it should have ``requires_grad`` off); then cut the first
    step to what the servos reach from ``current`` (4,) [rad] (``limits``) and predict the
    plan once more with it."""
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
