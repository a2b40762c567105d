"""The deep-RL baseline's training: Stable-Baselines3 (PPO or SAC) on the batched vector
environment of the laser (``ModeLockedLaser-v0``, docs/gym.md), over the plant family
and the drift scenarios, and the export of its policy to plain arrays
(:mod:`dlmpc_ros.learning.policy`).

The lasers are split into conditions (:class:`DRLCondition`: a drift scenario and an
initial field), each a :class:`~dlmpc_ros.gym.vector.ModeLockedLaserVectorEnv` whose
every reset draws a plant of the family (domain randomization; the held-out plants
101-108 are never drawn: :class:`DevelopmentPlants`). :class:`LaserVecEnv` makes them
one SB3 ``VecEnv``: it turns the observation into the policy's features, scales the
action from [-1, 1] to the env's change of the angles, and the reward (the measured O) by
a constant; all lanes of a condition start and end their episodes together, so an
episode's end resets every lane of it at once (no lane loses a period). Seeded: the same
seed gives the same training on the same machine (SB3 on one CPU thread).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.plants import PlantFamily
from dlmpc_ros.gym.vector import ModeLockedLaserVectorEnv
from dlmpc_ros.learning.policy import LearnedPolicy, PolicyFeatures, policy_spec

ALGORITHMS = ('ppo', 'sac')
#: Family seeds of the held-out plants (``dlmpc-evaluate --plant-family 101 ... 108``):
#: never trained on.
HELD_OUT_PLANTS = tuple(range(101, 109))


@dataclass(frozen=True)
class DevelopmentPlants:
    """``plant_source``: the family's plant of a seed, drawn unchecked as the env does
    without a source, except that a held-out seed is replaced by another (seed + 2^31)."""

    family: PlantFamily = field(default_factory=PlantFamily)

    def __call__(self, seed: int) -> tuple[CavityConfig, None]:
        if seed in HELD_OUT_PLANTS:
            seed += 2 ** 31
        return self.family.draw(seed, 0), None


@dataclass(frozen=True)
class DRLCondition:
    """A group of training lasers: their drift scenario (``ModeLockedLaser-v0``'s
    ``scenario``) and initial field (``noise``: cold starts, as the lock benchmark;
    ``sech``: a pulse, as the drift runs)."""

    scenario: str
    initial: str
    lanes: int


#: Cold starts with K held (the lock benchmark) and drifting slowly (``drift``), and
#: starts from a pulse on the slow drift and on the evaluation's random walk.
CONDITIONS = (DRLCondition('held', 'noise', 4), DRLCondition('drift', 'noise', 4),
              DRLCondition('drift', 'sech', 4), DRLCondition('random_walk', 'sech', 4))


@dataclass(frozen=True)
class DRLConfig:
    """How ``dlmpc-train drl`` trains (times in control periods of P = 10 round trips)."""

    algorithm: str = 'ppo'
    """``ppo`` or ``sac`` (Stable-Baselines3)."""
    total_steps: int = 300_000
    """Env steps (control periods, all lanes together)."""
    seed: int = 0
    conditions: tuple[DRLCondition, ...] = CONDITIONS
    episode_periods: int = 200
    """Periods of an episode (2,000 round trips)."""
    solver: dict = field(default_factory=lambda: {'scheme': 'strang', 'steps_per_round_trip': 8})
    """The training cavity's solver: the default grid (256 points) with 8 symmetric split
    steps per round trip (the shipped policy's; before 2026-12-05 the default was 32 of
    them), its O within about 0.004 of the default's (docs/gym.md)."""
    plant: str = 'family'
    """``family`` (a plant per reset, :class:`DevelopmentPlants`) or ``nominal``."""
    features: PolicyFeatures = field(default_factory=PolicyFeatures)
    reward_scale: float = 5.0
    """The reward is the measured O times this (O is about 0.2 when locked)."""
    detector_noise: float = 0.0
    """The env's detector noise (relative, per round trip)."""
    net: tuple[int, ...] = (64, 64)
    """Hidden layers of the policy (and of the value function or critics)."""
    ppo: dict = field(default_factory=lambda: {
        'n_steps': 256, 'batch_size': 512, 'n_epochs': 10, 'learning_rate': 3e-4,
        'gamma': 0.98, 'gae_lambda': 0.95, 'clip_range': 0.2, 'ent_coef': 0.0,
        'vf_coef': 0.5, 'max_grad_norm': 0.5, 'log_std_init': -1.0})
    """PPO's settings (``log_std_init`` goes to the policy)."""
    sac: dict = field(default_factory=lambda: {
        'buffer_size': 200_000, 'learning_starts': 2000, 'batch_size': 256, 'tau': 0.005,
        'gamma': 0.98, 'train_freq': 1, 'gradient_steps': 2, 'learning_rate': 3e-4,
        'ent_coef': 'auto'})
    """SAC's settings (per vector step of every lane: ``gradient_steps`` updates)."""

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f'DRLConfig.algorithm must be one of {ALGORITHMS}, '
                             f'got {self.algorithm!r}')
        if self.total_steps < 1 or self.episode_periods < 1 or not self.conditions:
            raise ValueError('DRLConfig needs total_steps, episode_periods >= 1 and a '
                             'condition')

    @property
    def lanes(self) -> int:
        return sum(c.lanes for c in self.conditions)

    def to_dict(self) -> dict:
        out = asdict(self)
        out['conditions'] = [asdict(c) for c in self.conditions]
        out['net'] = list(self.net)
        out.pop('ppo' if self.algorithm == 'sac' else 'sac')
        return out


def make_envs(config: DRLConfig, solver: dict | None = None, plant: str | None = None,
              conditions: Sequence[DRLCondition] | None = None, **options: Any
              ) -> list[ModeLockedLaserVectorEnv]:
    """One vector env per condition (``solver``, ``plant``, ``conditions`` and env
    ``options`` override the config's)."""
    plant = config.plant if plant is None else plant
    source = {'plant_source': DevelopmentPlants()} if plant == 'family' else {}
    settings = {'episode_periods': config.episode_periods, 'window': config.features.window,
                'detector_noise': config.detector_noise, **options}
    return [ModeLockedLaserVectorEnv(num_envs=c.lanes, threads=1, scenario=c.scenario,
                                     initial=c.initial, plant=plant, **source,
                                     solver=dict(config.solver if solver is None else solver),
                                     **settings)
            for c in (config.conditions if conditions is None else conditions)]


class LaserVecEnv(VecEnv):
    """The condition's vector envs as one Stable-Baselines3 ``VecEnv`` of the policy's
    features, actions in [-1, 1] and scaled rewards. Finished episodes are kept in
    :attr:`episodes` (step count at the end, condition, mean O, mean O / O* where known)."""

    def __init__(self, envs: Sequence[ModeLockedLaserVectorEnv], features: PolicyFeatures,
                 reward_scale: float = 1.0) -> None:
        self.envs = list(envs)
        self.features = features
        self.reward_scale = float(reward_scale)
        config = self.envs[0].config
        if config.action != 'delta' or config.window != features.window:
            raise ValueError("LaserVecEnv needs action='delta' envs observing "
                             f'{features.window} periods')
        self.action_scale = float(config.max_step)
        self.slices = []
        start = 0
        for env in self.envs:
            self.slices.append(slice(start, start + env.num_envs))
            start += env.num_envs
        box = spaces.Box(-np.inf, np.inf, (features.size,), np.float32)
        super().__init__(start, box, spaces.Box(-1.0, 1.0, (4,), np.float32))
        self.steps = 0
        self.episodes: list[tuple[int, int, float, float]] = []
        self._returns = np.zeros(start)
        self._ratios = np.zeros(start)
        self._lengths = np.zeros(start, np.int64)
        self._started = time.monotonic()
        self._actions = np.zeros((start, 4))

    def _features(self, observations: list[np.ndarray]) -> np.ndarray:
        return self.features(np.concatenate(observations))

    def reset(self) -> np.ndarray:
        observations = []
        for env, lanes in zip(self.envs, self.slices):
            seeds = self._seeds[lanes]
            obs, _ = env.reset(seed=None if seeds[0] is None else list(seeds))
            observations.append(obs)
        self._reset_seeds()
        self._reset_options()
        self._returns[:] = self._ratios[:] = self._lengths[:] = 0
        return self._features(observations)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.clip(np.asarray(actions, float), -1.0, 1.0) * self.action_scale

    def step_wait(self):
        observations, rewards, dones = [], [], []
        infos: list[dict[str, Any]] = []
        for g, (env, lanes) in enumerate(zip(self.envs, self.slices)):
            obs, reward, _, truncated, info = env.step(self._actions[lanes])
            self._returns[lanes] += reward
            self._ratios[lanes] += reward / info['O_star']
            self._lengths[lanes] += 1
            lane_infos: list[dict[str, Any]] = [{} for _ in range(env.num_envs)]
            if truncated.any():
                if not truncated.all():
                    raise RuntimeError('the lanes of a condition must end their episodes '
                                       'together')
                final = self.features(obs)
                for i, item in enumerate(lane_infos):
                    lane = lanes.start + i
                    mean = self._returns[lane] / self._lengths[lane]
                    ratio = self._ratios[lane] / self._lengths[lane]
                    item.update({'terminal_observation': final[i], 'TimeLimit.truncated': True,
                                 'episode': {'r': float(self._returns[lane] * self.reward_scale),
                                             'l': int(self._lengths[lane]),
                                             't': round(time.monotonic() - self._started, 6)}})
                    self.episodes.append((self.steps + self.num_envs, g, float(mean),
                                          float(ratio)))
                self._returns[lanes] = self._ratios[lanes] = self._lengths[lanes] = 0
                obs, _ = env.reset()
            observations.append(obs)
            rewards.append(reward * self.reward_scale)
            dones.append(truncated)
            infos += lane_infos
        self.steps += self.num_envs
        return (self._features(observations), np.concatenate(rewards).astype(np.float32),
                np.concatenate(dones), infos)

    def close(self) -> None:
        for env in self.envs:
            env.close()

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == 'render_mode':
            return [None] * len(self._indices(indices))
        raise AttributeError(f'LaserVecEnv has no attribute {attr_name!r} for its lanes')

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f'LaserVecEnv cannot set {attr_name!r} on its lanes')

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        raise AttributeError(f'LaserVecEnv has no lane method {method_name!r}')

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)


def make_model(config: DRLConfig, env: VecEnv):
    """The SB3 model of ``config`` on ``env`` (seeded; CPU, torch on one thread: the
    networks are small, and a team of threads on a shared machine costs more than it
    saves)."""
    import torch
    from stable_baselines3 import PPO, SAC
    torch.set_num_threads(1)
    if config.algorithm == 'ppo':
        settings = dict(config.ppo)
        log_std = settings.pop('log_std_init')
        return PPO('MlpPolicy', env, seed=config.seed, device='cpu', verbose=0,
                   policy_kwargs={'net_arch': {'pi': list(config.net), 'vf': list(config.net)},
                                  'activation_fn': torch.nn.Tanh, 'log_std_init': log_std},
                   **settings)
    return SAC('MlpPolicy', env, seed=config.seed, device='cpu', verbose=0,
               policy_kwargs={'net_arch': list(config.net)}, **config.sac)


def export_layers(model) -> tuple[list[tuple[np.ndarray, np.ndarray]], str, str]:
    """The deterministic policy network of an SB3 PPO or SAC model: its linear layers
    (weight, bias), the hidden activation and the output's squashing."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.torch_layers import FlattenExtractor
    if isinstance(model, PPO):
        policy = model.policy
        if policy.squash_output or not isinstance(policy.features_extractor, FlattenExtractor):
            raise ValueError('export needs a flat, unsquashed PPO MlpPolicy')
        modules = list(policy.mlp_extractor.policy_net) + [policy.action_net]
        output = 'clip'
    else:
        actor = model.actor
        modules = list(actor.latent_pi) + [actor.mu]
        output = 'tanh'
    layers, activations = [], set()
    for module in modules:
        if isinstance(module, torch.nn.Linear):
            layers.append((module.weight.detach().cpu().numpy().copy(),
                           module.bias.detach().cpu().numpy().copy()))
        elif isinstance(module, torch.nn.Tanh):
            activations.add('tanh')
        elif isinstance(module, torch.nn.ReLU):
            activations.add('relu')
        else:
            raise ValueError(f'cannot export a {type(module).__name__} layer')
    if len(activations) > 1:
        raise ValueError(f'the policy mixes activations {sorted(activations)}')
    return layers, (activations.pop() if activations else 'tanh'), output


def exported_policy(model, config: DRLConfig, training: dict) -> LearnedPolicy:
    """The model's deterministic policy as a :class:`LearnedPolicy` (with its spec)."""
    layers, activation, output = export_layers(model)
    limits = AngleLimits()
    spec = policy_spec(config.algorithm, activation, output, config.features,
                       limits.max_step,
                       {'id': 'ModeLockedLaser-v0', 'action': 'delta',
                        'window': config.features.window, 'low': limits.low,
                        'high': limits.high, 'period': 10, 'measurement_round_trips': 10},
                       training)
    spec['architecture']['layers'] = [list(w.shape) for w, _ in layers]
    return LearnedPolicy(layers, spec)


def train(config: DRLConfig, log: Callable[[str], None] | None = None
          ) -> tuple[Any, LaserVecEnv, dict]:
    """Train; returns the SB3 model, its env (with the finished episodes) and the
    training's figures (steps, wall seconds, env steps per second)."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)
    env = LaserVecEnv(make_envs(config), config.features, config.reward_scale)
    model = make_model(config, env)
    started = time.monotonic()

    class Report(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next = 0

        def _on_step(self) -> bool:
            if log is not None and env.steps >= self.next:
                self.next += max(config.total_steps // 20, env.num_envs)
                recent = [e[2] for e in env.episodes[-4 * env.num_envs:]]
                elapsed = time.monotonic() - started
                log(f'drl: {env.steps} of {config.total_steps} steps, {elapsed:.0f} s, '
                    f'{env.steps / max(elapsed, 1e-9):.0f} steps/s, mean O of the latest '
                    f'episodes {np.mean(recent) if recent else float("nan"):.4f}')
            return True

    model.learn(total_timesteps=config.total_steps, callback=Report())
    wall = time.monotonic() - started
    return model, env, {'steps': int(env.steps), 'wall_seconds': round(wall, 1),
                        'steps_per_second': round(env.steps / wall, 1)}


def evaluate_policy(policy: LearnedPolicy, envs: Sequence[ModeLockedLaserVectorEnv],
                    seed: int, episodes: int = 1) -> list[dict[str, float]]:
    """Run the deterministic ``policy`` (and, beside it, holding the angles) for
    ``episodes`` episodes of each env; per env: the mean O over the episodes, over their
    second half, and the mean O / O* where the env knows O*."""
    out = []
    for g, env in enumerate(envs):
        result: dict[str, float] = {}
        for name in ('policy', 'hold'):
            rewards, ratios = [], []
            for e in range(episodes):
                obs, _ = env.reset(seed=seed + 1000 * g + 100_000 * e)
                for _ in range(env.config.episode_periods):
                    actions = (policy.deltas(obs) if name == 'policy'
                               else np.zeros((env.num_envs, 4)))
                    obs, reward, _, _, info = env.step(actions)
                    rewards.append(reward)
                    ratios.append(reward / info['O_star'])
            rewards_a, ratios_a = np.array(rewards), np.array(ratios)
            half = len(rewards_a) // 2
            result[f'{name}_mean_O'] = float(rewards_a.mean())
            result[f'{name}_mean_O_second_half'] = float(rewards_a[half:].mean())
            result[f'{name}_O_over_O_star'] = (float(np.nanmean(ratios_a))
                                               if np.isfinite(ratios_a).any() else float('nan'))
        out.append(result)
    return out


def with_steps(config: DRLConfig, steps: int) -> DRLConfig:
    return replace(config, total_steps=int(steps))
