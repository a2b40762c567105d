"""``dlmpc-train drl``: the deep-RL baseline (:mod:`dlmpc_ros.training.drl`): train with
Stable-Baselines3 on the Gymnasium environment of the laser, export the deterministic
policy to ``models/drl_policy.npz`` + ``.json`` (no pickles; the SB3 archive is not
kept), check that the exported policy acts as SB3's and that the files load, measure it
on development episodes of the default cavity (beside holding the start angles), and
draw the reward curve (``models/figures/drl_reward.png``). Needs no ``data/``.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import replace
from importlib import metadata
from pathlib import Path

import numpy as np

from dlmpc_ros.learning.policy import FILE_NAME, load_policy, save_policy
from dlmpc_ros.training.drl import (DRLCondition, DRLConfig, LaserVecEnv, evaluate_policy,
                                    exported_policy, make_envs, train)
from dlmpc_ros.training.workspace import Workspace

#: The development episodes measured after training, on the default cavity (plant,
#: condition): the nominal plant drifting slowly from a pulse (its envelope gives O / O*)
#: and family plants from cold starts with K held.
DEVELOPMENT = (('nominal', DRLCondition('drift', 'sech', 8)),
               ('family', DRLCondition('held', 'noise', 8)))
FIGURE = 'drl_reward.png'


def quick_config(seed: int) -> DRLConfig:
    """A few hundred steps on a 64-point cavity (tests)."""
    base = DRLConfig()
    return DRLConfig(seed=seed, total_steps=256, episode_periods=32,
                     conditions=(DRLCondition('held', 'noise', 2),
                                 DRLCondition('drift', 'sech', 2)),
                     solver={'points': 64, 'steps_per_round_trip': 8, 'scheme': 'strang'},
                     ppo={**base.ppo, 'n_steps': 32, 'batch_size': 64, 'n_epochs': 2})


def machine() -> dict:
    """Where the training ran."""
    versions = {}
    for package in ('stable-baselines3', 'torch', 'gymnasium', 'numpy'):
        try:
            versions[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            versions[package] = None
    return {'platform': platform.platform(), 'processor': platform.processor() or
            platform.machine(), 'cpu_count': os.cpu_count(), 'torch_threads': 1,
            'load_average_1min': round(os.getloadavg()[0], 2),
            'python': platform.python_version(), **versions}


def export_difference(model, policy, seed: int, samples: int = 256) -> float:
    """Largest |exported action - SB3's deterministic action| on random observations."""
    rng = np.random.default_rng(seed)
    w = policy.window
    obs = np.concatenate([rng.uniform(0, 8, (samples, w, 1)), rng.uniform(1, 60, (samples, w, 1)),
                          rng.uniform(-2 * np.pi, 2 * np.pi, (samples, w, 4))], axis=-1)
    obs = obs.reshape(samples, -1).astype(np.float32)
    theirs, _ = model.predict(policy.features(obs), deterministic=True)
    return float(np.abs(policy.act(obs) - theirs).max())


def reward_curve(env: LaserVecEnv, conditions, path: Path, title: str) -> dict:
    """Mean O of the finished episodes over training steps, per condition and over all;
    writes the figure; returns the curve (per rollout of finished episodes)."""
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    episodes = np.array(env.episodes, float).reshape(-1, 4)
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    curve: dict = {'steps': [], 'mean_O': []}
    if episodes.size:
        ends = np.unique(episodes[:, 0])
        curve = {'steps': ends.astype(int).tolist(),
                 'mean_O': [float(episodes[episodes[:, 0] == s, 2].mean()) for s in ends]}
        for g, c in enumerate(conditions):
            rows = episodes[episodes[:, 1] == g]
            if rows.size:
                ax.plot(rows[:, 0], rows[:, 2], '.', ms=2, alpha=0.5,
                        label=f'{c.scenario}, {c.initial} start')
        ax.plot(curve['steps'], curve['mean_O'], 'k-', lw=1.5, label='all lanes')
    ax.set_xlabel('env steps (control periods, all lanes)')
    ax.set_ylabel('mean measured O of an episode')
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return curve


def train_drl_stage(ws: Workspace, seed: int, quick: bool = False,
                    show_progress: bool = True, config: DRLConfig | None = None) -> dict:
    """Train, export, check and measure the policy; writes the model files and the figure
    into ``ws.models_dir``; returns the metrics."""
    config = config or (quick_config(seed) if quick else DRLConfig(seed=seed))
    config = replace(config, seed=seed)
    log = print if show_progress else None
    load_before = round(os.getloadavg()[0], 2)
    model, env, figures = train(config, lambda line: log(line, flush=True) if log else None)
    note = {'algorithm': config.algorithm, 'seed': seed, 'made_by': 'dlmpc-train drl',
            **figures}
    policy = exported_policy(model, config, note)
    difference = export_difference(model, policy, seed)
    if not difference < 1e-4:
        raise ValueError(f'the exported policy differs from SB3\'s by {difference:g}')
    save_policy(ws.models_dir, policy.layers, policy.spec)
    policy = load_policy(ws.models_dir)
    started = time.monotonic()
    dev = {}
    for plant, condition in DEVELOPMENT:
        condition = replace(condition, lanes=1) if quick else condition
        envs = make_envs(config, solver=config.solver if quick else {}, plant=plant,
                         conditions=[condition])
        dev[f'{plant}_{condition.scenario}_{condition.initial}'] = {
            'lanes': condition.lanes, **evaluate_policy(policy, envs, seed=10_000 + seed)[0]}
    dev_seconds = time.monotonic() - started
    title = (f'{config.algorithm.upper()} on ModeLockedLaser-v0, {env.num_envs} lanes, family '
             f'plants, seed {seed}')
    curve = reward_curve(env, config.conditions, ws.figures / FIGURE, title)
    last = curve['mean_O'][-5:]
    return {'file': FILE_NAME, 'algorithm': config.algorithm, 'seed': seed,
            'steps': figures['steps'], 'wall_seconds': figures['wall_seconds'],
            'steps_per_second': figures['steps_per_second'],
            'episodes': len(env.episodes), 'final_mean_O': float(np.mean(last)) if last else None,
            'export_max_difference': difference, 'config': config.to_dict(),
            'machine': {**machine(), 'load_average_1min_before': load_before},
            'development': dev,
            'development_seconds': round(dev_seconds, 1), 'figure': f'figures/{FIGURE}',
            'curve': curve}
