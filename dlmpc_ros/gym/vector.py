"""``ModeLockedLaser-v0`` as a vector environment: B lasers in one batched cavity, one
kernel call per round trip for all of them (``Cavity(batch=B)``), instead of B Python
environments.

Sub-environment i behaves exactly as a :class:`~dlmpc_ros.gym.env.ModeLockedLaserEnv`
reset with seed ``seed + i`` (a list of seeds: its own): same observations, rewards and
info. Autoreset follows Gymnasium 1.x's next-step rule (``metadata['autoreset_mode']``):
the step after a sub-environment's episode ended resets it (its action is ignored; reward
0, not terminated or truncated) and returns its first observation. ``reset(options=
{'reset_mask': mask})`` resets only the lanes in ``mask``; the others hold their angles
for the period that the reset lanes' first measurement takes (their episodes go on by a
period, with no reward returned for it).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numba
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from dlmpc_ros.gym.env import check_actions, make_config, make_spaces
from dlmpc_ros.gym.lasers import LaserBatch


class ModeLockedLaserVectorEnv(VectorEnv):
    """B lasers. Keyword arguments: ``num_envs``, ``threads`` (numba threads of the
    batched kernel during this env's calls; None: numba's setting, every core; on a
    loaded machine 1 can be faster, ``bench/results/bench_gym.md``) and the fields of
    :class:`~dlmpc_ros.gym.config.LaserEnvConfig`."""

    metadata: dict[str, Any] = {'render_modes': [], 'autoreset_mode': AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, threads: int | None = None, **options: Any) -> None:
        cores = numba.config.NUMBA_NUM_THREADS
        if threads is not None and (isinstance(threads, bool) or not isinstance(
                threads, (int, np.integer)) or not 1 <= threads <= cores):
            raise ValueError(f'ModeLockedLaser option threads must be None or an integer in '
                             f'[1, {cores}], got {threads!r}')
        self.threads = threads
        self.config = make_config(options)
        self._lasers = LaserBatch(self.config, num_envs)
        self.num_envs = self._lasers.batch
        self.single_observation_space, self.single_action_space = make_spaces(self.config)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        assert isinstance(self.action_space, spaces.Box)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._steps = np.zeros(self.num_envs, np.int64)
        self._done = np.zeros(self.num_envs, bool)
        self._started = False

    def reset(self, *, seed: int | list[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        B = self.num_envs
        options = dict(options or {})
        mask = np.asarray(options.pop('reset_mask', np.ones(B, bool)))
        if options:
            raise ValueError(f'ModeLockedLaser reset takes only reset_mask, got '
                             f'{sorted(options)}; give settings to gymnasium.make_vec')
        if mask.dtype != bool or mask.shape != (B,):
            raise ValueError(f'ModeLockedLaser reset_mask must be a bool array of shape ({B},)')
        if not self._started and not mask.all():
            raise ValueError('ModeLockedLaser: the first reset must reset every laser')
        if seed is None or isinstance(seed, (int, np.integer)):
            seeds: list[int | None] = ([None] * B if seed is None
                                       else [int(seed) + i for i in range(B)])
        else:
            seeds = list(seed)
            if len(seeds) != B:
                raise ValueError(f'ModeLockedLaser reset needs {B} seeds, got {len(seeds)}')
        for i in np.flatnonzero(mask):
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
            self._lasers.begin(int(i), self._rngs[i])
        # every lane runs the period (the lanes not reset hold their angles; their
        # episodes go on by a period, as any batched step would move them)
        with self._kernel_threads():
            result = self._lasers.period(None)
        self._steps[mask] = 0
        self._done[mask] = False
        self._started = True
        return self._lasers.observation(), vector_info(result.info)

    def step(self, actions: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError('ModeLockedLaser: call reset() before step()')
        B = self.num_envs
        actions = check_actions(actions, (B, 4))
        restart = self._done.copy()
        for i in np.flatnonzero(restart):
            self._lasers.begin(int(i), self._rngs[i])
        with self._kernel_threads():
            result = self._lasers.period(actions, move=~restart)
        self._steps = np.where(restart, 0, self._steps + 1)
        truncated = ~restart & (self._steps >= self.config.episode_periods)
        self._done = truncated.copy()
        reward = np.where(restart, 0.0, result.reward)
        return (self._lasers.observation(), reward, np.zeros(B, bool), truncated,
                vector_info(result.info))

    @contextmanager
    def _kernel_threads(self) -> Iterator[None]:
        """numba's threads set to ``threads`` for the block (numba's setting is per
        calling thread), restored after."""
        if self.threads is None:
            yield
            return
        before = numba.get_num_threads()
        numba.set_num_threads(int(self.threads))
        try:
            yield
        finally:
            numba.set_num_threads(before)


def vector_info(info: dict[str, np.ndarray]) -> dict[str, Any]:
    """Gymnasium's vector info: every key for every lane, with its ``_key`` mask."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        out[key] = value
        out[f'_{key}'] = np.ones(value.shape[0], bool)
    return out
