"""Angle limits and servo speed: turning a wanted angle set into an applicable one."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AngleLimits:
    """Range of every angle [rad] and the largest change per control period [rad].

    Angles are pi-periodic: a wanted angle becomes its equivalent in ``[low, high]`` (which
    should span >= pi) nearest the current one, reached by at most ``max_step`` per period.
    """

    low: float = -2 * math.pi
    """Lowest angle a servo may be sent to [rad] (two turns: room for branch turns)."""
    high: float = 2 * math.pi
    """Highest angle a servo may be sent to [rad]."""
    max_step: float = 0.25
    """Largest change of any angle per control period [rad] (servo speed)."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ValueError(f'angle limits must be finite with low < high, got '
                             f'[{self.low}, {self.high}]')
        if not self.max_step > 0:
            raise ValueError(f'max_step must be > 0 rad, got {self.max_step}')

    def apply(self, current: np.ndarray, wanted: np.ndarray) -> np.ndarray:
        """The angles (4,) [rad] to command, from the current (4,) and the wanted (4,) ones:
        toward the pi-equivalent of ``wanted`` in range nearest ``current``, by <= ``max_step``."""
        current = np.clip(np.asarray(current, float), self.low, self.high)
        wanted = np.asarray(wanted, float)
        goal = wanted + math.pi * np.round((current - wanted) / math.pi)  # nearest of all
        goal = into_range(goal, self.low, self.high)
        reachable = (goal >= self.low) & (goal <= self.high)   # a range narrower than pi
        goal = np.where(reachable, goal, np.clip(wanted, self.low, self.high))
        return current + np.clip(goal - current, -self.max_step, self.max_step)


def into_range(goal: np.ndarray, low: float, high: float) -> np.ndarray:
    """Angles (any shape) [rad] beyond a limit moved by whole multiples of pi to the nearest
    equivalent in ``[low, high]`` (still outside if the range is under pi), others unchanged."""
    goal = np.where(goal > high, goal - math.pi * np.ceil((goal - high) / math.pi), goal)
    return np.where(goal < low, goal + math.pi * np.ceil((low - goal) / math.pi), goal)
