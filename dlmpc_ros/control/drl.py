"""The deep-RL baseline: a policy trained with Stable-Baselines3 on the Gymnasium
environment of the laser (``dlmpc-train drl``, docs/gym.md), run as a controller.

Each period it appends the measurement ``(E, M, alpha[4])`` to the window of past periods
the policy observes, forms the observation exactly as ``ModeLockedLaser-v0`` does (the
same code: :mod:`dlmpc_ros.control.observation`; the first measurement fills the window,
as at an episode's reset), and commands the policy's change of the angles from its last
command (the env's ``delta`` action), within the servo limits. It reads nothing but its
measurements and its model file (numpy; no torch, no gymnasium); a measurement that is no
laser's holds the angles and stays out of the window.
"""

from __future__ import annotations

import time

import numpy as np

from dlmpc_ros.control.step import AngleLimits, ControlStep, implausible
from dlmpc_ros.control.observation import MeasurementWindow, delta_commands
from dlmpc_ros.learning.policy import LearnedPolicy


class DRLController:
    """Runs a :class:`~dlmpc_ros.learning.policy.LearnedPolicy` within ``limits``."""

    name = 'drl'

    def __init__(self, policy: LearnedPolicy, limits: AngleLimits | None = None) -> None:
        self.policy = policy
        self.limits = limits or AngleLimits()
        env = policy.spec['environment']
        self._window = MeasurementWindow(1, policy.window, float(env['low']), float(env['high']))
        self._target: np.ndarray | None = None

    def fresh(self) -> DRLController:
        """A controller with the same policy and limits and no history."""
        return DRLController(self.policy, self.limits)

    def observation(self) -> np.ndarray:
        """(window * 6,) float32: what the policy observes now."""
        return self._window.observation()[0]

    def step(self, measurement: np.ndarray, surrogate: float | None = None) -> ControlStep:
        started = time.perf_counter()
        measurement = np.asarray(measurement, float)
        if measurement.shape != (6,):
            raise ValueError('measurement must be (E, M, alpha1, alpha2, alpha3, alpha_p), '
                             f'got shape {measurement.shape}')
        if implausible(measurement):  # a glitch: hold the last command (or the angles)
            held = self._target if self._target is not None else np.clip(
                np.nan_to_num(measurement[2:6], nan=0.0), self.limits.low, self.limits.high)
            return ControlStep(angles=held.copy(), mode='hold',
                               latency_ms=1e3 * (time.perf_counter() - started))
        first = self._target is None
        if first:
            self._target = np.clip(measurement[2:6], self.limits.low, self.limits.high)
        self._window.push(measurement[None], np.array([first]))
        delta = self.policy.deltas(self._window.observation())[0]
        self._target = delta_commands(self._target, delta, self.limits)
        return ControlStep(angles=self._target.copy(), mode='drl', iterations=1,
                           latency_ms=1e3 * (time.perf_counter() - started))
