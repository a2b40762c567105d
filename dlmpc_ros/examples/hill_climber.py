"""A coordinate-wise hill climber on the measured O = E / M (docs/controllers.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.control.step import AngleLimits, ControlStep, implausible


class HillClimber:
    """Tries one angle +-``delta`` at a time: keeps a trial that raised O, else tries the
    next one from the kept angles. The kept O fades by ``forget`` a period, so that a
    drift of the laser does not leave it chasing an O it can no longer reach."""

    name = 'hill_climber'

    def __init__(self, limits: AngleLimits, delta: float = 0.05, forget: float = 0.999):
        self.limits, self.delta, self.forget = limits, delta, forget
        self.kept, self.kept_o, self.trial = None, -np.inf, 0

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        e, m, angles = measurement[0], measurement[1], measurement[2:6]
        if implausible(measurement):  # no laser's (a glitch, a corrupt driver): hold
            return ControlStep(angles=self.limits.apply(angles, angles), mode='hold')
        o = e / m  # what the period measured at ``angles``
        if self.kept is None or o > self.kept_o:
            self.kept, self.kept_o = angles.copy(), o  # first period, or the trial paid
        else:
            self.trial = (self.trial + 1) % 8  # it did not: the next angle or direction
        self.kept_o *= self.forget
        wanted = self.kept.copy()
        wanted[self.trial // 2] += self.delta if self.trial % 2 == 0 else -self.delta
        return ControlStep(angles=self.limits.apply(angles, wanted), mode='custom')


def make(models_dir: Path, limits: AngleLimits) -> HillClimber:
    """The factory: ``--controller dlmpc_ros.examples.hill_climber:make`` (no model file)."""
    return HillClimber(limits)
