"""Factories for the plug-in tests: one that names the settings it wants, and ones
that fail in each way a harness must report in one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dlmpc_ros.control.step import AngleLimits, ControlStep


class Holder:
    """Holds the angles; remembers what its factory was given."""

    name = 'holder'

    def __init__(self, models_dir: Path, limits: AngleLimits, settings: dict) -> None:
        self.models_dir, self.limits, self.settings = models_dir, limits, settings

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        return ControlStep(angles=self.limits.apply(measurement[2:6], measurement[2:6]),
                           mode='hold')


def wants_angles(models_dir: Path, limits: AngleLimits, *, angles=None, **settings) -> Holder:
    return Holder(models_dir, limits, {'angles': angles, **settings})


def raises(models_dir: Path, limits: AngleLimits) -> Holder:
    raise FileNotFoundError('no calibration in\nthis lab')


def not_a_controller(models_dir: Path, limits: AngleLimits) -> str:
    return 'a string'
