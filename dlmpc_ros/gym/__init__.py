"""A Gymnasium environment of the mode-locked laser (docs/gym.md).

Importing this module registers ``ModeLockedLaser-v0``, so both
``gymnasium.make("dlmpc_ros.gym:ModeLockedLaser-v0", ...)`` and, after ``import
dlmpc_ros.gym``, ``gymnasium.make("ModeLockedLaser-v0", ...)`` work;
``gymnasium.make_vec(..., num_envs=B)`` gives the batched vector environment. Needs
``gymnasium`` (``pip install dlmpc_ros[gym]``); nothing else in the package imports it.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from dlmpc_ros.gym.config import LaserEnvConfig
from dlmpc_ros.gym.env import ModeLockedLaserEnv
from dlmpc_ros.gym.vector import ModeLockedLaserVectorEnv

ENV_ID = 'ModeLockedLaser-v0'

if ENV_ID not in registry:
    register(id=ENV_ID, entry_point='dlmpc_ros.gym.env:ModeLockedLaserEnv',
             vector_entry_point='dlmpc_ros.gym.vector:ModeLockedLaserVectorEnv',
             disable_env_checker=False)

__all__ = ['ENV_ID', 'LaserEnvConfig', 'ModeLockedLaserEnv', 'ModeLockedLaserVectorEnv']
