"""What a learned policy observes and how its action becomes a command: one code for the
Gymnasium environment (``dlmpc_ros.gym``, docs/gym.md) and for the controllers that run
a policy trained on it (``control/drl.py``), so that the two cannot drift apart.

The observation is a window of the latest control periods' measurements ``(E, M,
alpha[4])``, oldest first, clipped into :func:`observation_bounds` (a fresh window, at
the start of an episode or a run, is the first measurement repeated). A ``delta``
action is the change of the angles [rad], at most ``max_step`` each, from the last
command, the result clipped into the servo range (:func:`delta_commands`). Numpy only;
no gymnasium.
"""

from __future__ import annotations

import numpy as np

from dlmpc_ros.control.step import AngleLimits

#: Columns of a measurement: E, M and the four angles [rad].
MEASUREMENT = ('E', 'M', 'alpha1', 'alpha2', 'alpha3', 'alpha_p')
#: Observation bounds of E and M (``control/step.py`` E_RANGE, M_RANGE; a reading below
#: M = 1 by detector noise is kept).
E_BOUNDS, M_BOUNDS = (0.0, 1e4), (0.0, 1e5)


def observation_bounds(window: int, low: float, high: float) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (window * 6,) of an observation of ``window`` periods with
    angles in [low, high]."""
    lower = np.array([E_BOUNDS[0], M_BOUNDS[0], *[low] * 4])
    upper = np.array([E_BOUNDS[1], M_BOUNDS[1], *[high] * 4])
    return np.tile(lower, window), np.tile(upper, window)


class MeasurementWindow:
    """The latest ``window`` measurements of B lasers, oldest first."""

    def __init__(self, batch: int, window: int, low: float, high: float) -> None:
        self.batch, self.window = int(batch), int(window)
        self.values = np.zeros((self.batch, self.window, len(MEASUREMENT)))
        self.bounds = observation_bounds(self.window, low, high)

    def push(self, measurement: np.ndarray, fresh: np.ndarray) -> None:
        """Append each laser's measurement (B, 6); a ``fresh`` (B,) laser's window is
        filled with it (its episode or run begins)."""
        measurement = np.asarray(measurement, float)
        fresh = np.asarray(fresh, bool)
        self.values[~fresh] = np.roll(self.values[~fresh], -1, axis=1)
        self.values[:, -1] = measurement
        self.values[fresh] = measurement[fresh, None, :]

    def observation(self) -> np.ndarray:
        """(B, window * 6) float32: the window, oldest first, clipped into the bounds."""
        low, high = self.bounds
        return np.clip(self.values.reshape(self.batch, -1), low, high).astype(np.float32)


def delta_commands(target: np.ndarray, actions: np.ndarray, limits: AngleLimits) -> np.ndarray:
    """The commands [rad] that the changes ``actions`` give from the last commands
    ``target`` (same shape, (..., 4)): each change clipped to ``limits.max_step``, the
    result into ``[limits.low, limits.high]``."""
    step = np.clip(np.asarray(actions, float), -limits.max_step, limits.max_step)
    return np.clip(np.asarray(target, float) + step, limits.low, limits.high)
