"""The deep-RL baseline (``dlmpc-train drl``, ``--controller drl``): the exported policy
acts as Stable-Baselines3's, its files round-trip and fail in one clear line, the
controller observes what the env observes, and a tiny training run makes a loadable file.
On a 64-point cavity, a few periods (about 10 s in all)."""

import json
import shutil

import numpy as np
import pytest

from dlmpc_ros.cli.train import main as train_main
from dlmpc_ros.control.drl import DRLController
from dlmpc_ros.control.step import AngleLimits
from dlmpc_ros.control.plugins import ControllerSpecError, build
from dlmpc_ros.learning.model_files import ModelFileError
from dlmpc_ros.learning.policy import FILE_NAME, SPEC_NAME, load_policy, save_policy
from dlmpc_ros.training.drl import (DevelopmentPlants, DRLCondition, DRLConfig, LaserVecEnv,
                                    exported_policy, make_envs, make_model)

SMALL = {'points': 64, 'steps_per_round_trip': 8, 'scheme': 'strang'}


def _config(algorithm='ppo', total_steps=64):
    base = DRLConfig()
    return DRLConfig(algorithm=algorithm, total_steps=total_steps, episode_periods=8,
                     conditions=(DRLCondition('held', 'noise', 2),), solver=SMALL,
                     ppo={**base.ppo, 'n_steps': 16, 'batch_size': 32, 'n_epochs': 1},
                     sac={**base.sac, 'learning_starts': 16, 'buffer_size': 1000})


def _observations(n=64, window=4, seed=0):
    rng = np.random.default_rng(seed)
    obs = np.concatenate([rng.uniform(0, 8, (n, window, 1)), rng.uniform(0.5, 60, (n, window, 1)),
                          rng.uniform(-2 * np.pi, 2 * np.pi, (n, window, 4))], axis=-1)
    return obs.reshape(n, -1).astype(np.float32)


@pytest.fixture(scope='module')
def trained(tmp_path_factory):
    """PPO and SAC models (briefly trained) and their exported policies, saved."""
    out = {}
    for algorithm in ('ppo', 'sac'):
        config = _config(algorithm)
        env = LaserVecEnv(make_envs(config), config.features, config.reward_scale)
        model = make_model(config, env)
        model.learn(total_timesteps=config.total_steps)
        directory = tmp_path_factory.mktemp(algorithm)
        policy = exported_policy(model, config, {'note': algorithm})
        save_policy(directory, policy.layers, policy.spec)
        out[algorithm] = (model, policy, directory)
    return out


@pytest.mark.parametrize('algorithm', ['ppo', 'sac'])
def test_the_exported_policy_round_trips_and_acts_as_sb3_s(trained, algorithm):
    model, policy, directory = trained[algorithm]
    loaded = load_policy(directory)
    obs = _observations()
    theirs, _ = model.predict(policy.features(obs), deterministic=True)
    assert np.abs(loaded.act(obs) - theirs).max() < 1e-5
    assert np.array_equal(loaded.act(obs), policy.act(obs))
    assert loaded.spec['training'] == {'note': algorithm}
    assert np.abs(loaded.deltas(obs)).max() <= 0.25
    with np.load(directory / FILE_NAME, allow_pickle=False) as data:  # plain arrays only
        assert all(data[k].dtype != object for k in data.files)


def test_a_missing_or_corrupt_policy_file_names_the_command_that_makes_it(trained, tmp_path):
    _, _, directory = trained['ppo']
    with pytest.raises(ModelFileError, match=r'missing; regenerate it with `dlmpc-train drl`'):
        load_policy(tmp_path)
    with pytest.raises(ControllerSpecError, match='dlmpc-train drl'):  # in every harness
        build('drl', tmp_path)

    def broken(name, change):
        target = tmp_path / name
        shutil.copytree(directory, target)
        change(target)
        return target

    cases = {
        'truncated weights': lambda d: (d / FILE_NAME).write_bytes(
            (directory / FILE_NAME).read_bytes()[:100]),
        'no description': lambda d: (d / SPEC_NAME).unlink(),
        'description not JSON': lambda d: (d / SPEC_NAME).write_text('{'),
        'other schema': lambda d: (d / SPEC_NAME).write_text(json.dumps(
            {**json.loads((d / SPEC_NAME).read_text()), 'schema_version': 99})),
        'layers not as described': lambda d: (d / SPEC_NAME).write_text(json.dumps(
            {**json.loads((d / SPEC_NAME).read_text()),
             'features': {'window': 2}})),
    }
    for i, (what, change) in enumerate(cases.items()):
        with pytest.raises(ModelFileError, match='dlmpc-train drl') as err:
            load_policy(broken(f'case{i}', change))
        assert '\n' not in str(err.value), what


def test_the_controller_observes_and_commands_what_the_env_does(trained):
    import gymnasium

    import dlmpc_ros.gym  # noqa: F401

    _, policy, _ = trained['ppo']
    env = gymnasium.make('ModeLockedLaser-v0', solver=SMALL, window=policy.window,
                         scenario='drift', initial='noise', episode_periods=12,
                         detector_noise=0.01)
    lasers = env.unwrapped._lasers
    obs, _ = env.reset(seed=3)
    controller = DRLController(policy, AngleLimits())
    for _ in range(10):
        measurement = lasers.window.values[0, -1].copy()   # the period's (E, M, angles)
        step = controller.step(measurement)
        assert np.array_equal(controller.observation(), obs) and step.mode == 'drl'
        obs, *_ = env.step(policy.deltas(obs[None])[0])
        assert np.array_equal(lasers.servos.target[0], step.angles)
    # a glitch holds the last command and stays out of the window
    before = controller.observation()
    held = controller.step(np.array([np.nan, 1.0, 0.0, 0.0, 0.0, 0.0]))
    assert held.mode == 'hold' and np.array_equal(held.angles, step.angles)
    assert np.array_equal(controller.observation(), before)
    assert controller.fresh().observation().sum() == 0


def test_training_is_seeded_and_never_draws_a_held_out_plant():
    weights = []
    for _ in range(2):
        config = _config(total_steps=32)
        env = LaserVecEnv(make_envs(config), config.features, config.reward_scale)
        model = make_model(config, env)
        model.learn(total_timesteps=config.total_steps)
        weights.append(exported_policy(model, config, {}).layers[0][0])
    assert np.array_equal(*weights)
    plants = DevelopmentPlants()
    assert plants(101)[0] != plants.family.draw(101, 0)
    assert plants(7)[0] == plants.family.draw(7, 0)


def test_a_tiny_training_run_makes_a_loadable_policy_and_its_card(tmp_path):
    models = tmp_path / 'models'
    assert train_main(['drl', '--quick', '--no-progress', '--models-dir', str(models),
                       '--data-dir', str(tmp_path / 'data')]) == 0
    controller = build('drl', models, AngleLimits())
    step = controller.step(np.array([2.0, 15.0, 0.1, -0.2, 0.3, 0.4]))
    assert step.mode == 'drl' and np.isfinite(step.angles).all()
    metrics = json.loads((models / 'metrics.json').read_text())['drl']
    assert metrics['steps'] >= 256 and metrics['export_max_difference'] < 1e-5
    assert (models / 'figures' / 'drl_reward.png').stat().st_size > 1000
    card = (models / 'MODEL_CARD.md').read_text()
    assert 'Deep-RL baseline' in card and 'drl_reward.png' in card
