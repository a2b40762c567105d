"""``ModeLockedLaser-v0``: one mode-locked fiber laser, one control period per step.

Observation (float32, ``window * 6``): per period, oldest first, the measured E and M
(the mean of the period's last min(n, P) round trips, with the bench's detector noise)
and the four angles the encoders report [rad]: what a controller sees. Action (4,): an
increment of the angles in [-max_step, max_step] [rad] (``action='delta'``, the default)
or the wanted angles in [low, high] (``absolute``). Reward: the measured O = E / M of the
period after the action. ``info`` carries what no controller may see, for logging only:
the true K, the envelope O*(K), the noise-free O, the plant (``lasers.INFO_KEYS``).
See docs/gym.md.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from dlmpc_ros.gym.config import LaserEnvConfig
from dlmpc_ros.gym.lasers import LaserBatch, action_bounds, observation_bounds


def make_spaces(config: LaserEnvConfig) -> tuple[spaces.Box, spaces.Box]:
    """The observation and action spaces of one laser."""
    low, high = observation_bounds(config)
    a_low, a_high = action_bounds(config)
    return (spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32),
            spaces.Box(a_low.astype(np.float32), a_high.astype(np.float32), dtype=np.float32))


def check_reset_options(options: dict[str, Any] | None) -> None:
    """reset() takes no options (the settings are the constructor's); ValueError."""
    if options:
        raise ValueError(f'ModeLockedLaser reset takes no options, got {sorted(options)}; '
                         'give settings to gymnasium.make')


def check_actions(actions: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The actions as floats of ``shape``; ValueError for another shape or a non-finite value."""
    actions = np.asarray(actions, dtype=float)
    if actions.shape != shape:
        raise ValueError(f'ModeLockedLaser action must have shape {shape}, got {actions.shape}')
    if not np.isfinite(actions).all():
        raise ValueError('ModeLockedLaser action must be finite')
    return actions


class ModeLockedLaserEnv(gymnasium.Env):
    """One laser. Keyword arguments: the fields of :class:`LaserEnvConfig`."""

    metadata: dict[str, Any] = {'render_modes': []}

    def __init__(self, **options: Any) -> None:
        self.config = make_config(options)
        self.observation_space, self.action_space = make_spaces(self.config)
        self._lasers = LaserBatch(self.config, 1)
        self._steps = 0
        self._started = False

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        check_reset_options(options)
        self._lasers.begin(0, self.np_random)
        result = self._lasers.period()
        self._steps, self._started = 0, True
        return self._lasers.observation()[0], lane_info(result.info, 0)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if not self._started:
            raise RuntimeError('ModeLockedLaser: call reset() before step()')
        actions = check_actions(action, (4,))
        result = self._lasers.period(actions[None])
        self._steps += 1
        truncated = self._steps >= self.config.episode_periods
        return (self._lasers.observation()[0], float(result.reward[0]), False, truncated,
                lane_info(result.info, 0))


def make_config(options: dict[str, Any]) -> LaserEnvConfig:
    """The configuration of keyword options; ValueError naming an unknown one."""
    known = LaserEnvConfig.__dataclass_fields__
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ValueError(f'unknown ModeLockedLaser option(s) {unknown}; known: '
                         f'{", ".join(known)}')
    return LaserEnvConfig(**options)


def lane_info(info: dict[str, np.ndarray], lane: int) -> dict[str, Any]:
    """One lane's info: Python scalars, the plant an array (8,)."""
    return {key: value[lane].copy() if value.ndim > 1 else value[lane].item()
            for key, value in info.items()}
