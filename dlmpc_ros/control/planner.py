"""The DL-MPC's planner: gradient ascent of the MP-RNN's predicted objective over N future
angle sets (paper section 3D), as a problem object in and a result object out."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dlmpc_ros.control.limits import AngleLimits
from dlmpc_ros.learning.mprnn import MPRNN


@dataclass(frozen=True)
class PlanProblem:
    """One receding-horizon plan: maximize the summed predicted O over the horizon."""

    history: torch.Tensor
    """(1, N + 2b, 10) features of the recent control periods, the last one now."""
    seed: torch.Tensor
    """(N, 4) first guess of the plan [rad] (the previous plan shifted, or the map's)."""
    current: np.ndarray
    """(4,) angles applied now [rad]."""
    iterations: int
    """Adam steps of the ascent."""
    learning_rate: float
    """Adam step size [rad]."""


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


def solve_plan(model: MPRNN, problem: PlanProblem, limits: AngleLimits) -> PlanResult:
    """Improve ``problem.seed`` by gradient ascent on ``model``'s summed predicted O (weights
    unchanged: it should have ``requires_grad`` off), then cut the first step to what the
    servos reach (``limits``) and predict the plan once more with it."""
    plan = problem.seed.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([plan], lr=problem.learning_rate)
    for _ in range(problem.iterations):
        optimizer.zero_grad()
        out = model(problem.history, plan[None])
        (-out.objective.sum()).backward()
        optimizer.step()
    plan = plan.detach()
    plan[0] = torch.as_tensor(limits.apply(problem.current, plan[0].numpy()), dtype=plan.dtype)
    with torch.no_grad():
        out = model(problem.history, plan[None])
    return PlanResult(first=plan[0].numpy().copy(), plan=plan,
                      predicted_objective=out.objective[0].numpy(),
                      predicted_next=out.v[0, 0], iterations=problem.iterations)
