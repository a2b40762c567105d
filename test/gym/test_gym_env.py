"""ModeLockedLaser-v0: Gymnasium's checker, seeding, the vector env against single envs,
the bench's effects and bad options. A small cavity and few periods keep it fast."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.plants import PHYSICS_FIELDS, PlantFamily

ENV = 'dlmpc_ros.gym:ModeLockedLaser-v0'
SMALL = {'points': 64, 'steps_per_round_trip': 8, 'scheme': 'strang'}


def make(**options):
    return gymnasium.make(ENV, **{'solver': SMALL, **options})


def rollout(env, seed: int, steps: int, actions: np.ndarray) -> tuple[list, list, list]:
    obs, info = env.reset(seed=seed)
    observations, rewards, infos = [obs], [], [info]
    for t in range(steps):
        obs, reward, _, _, info = env.step(actions[t])
        observations.append(obs)
        rewards.append(reward)
        infos.append(info)
    return observations, rewards, infos


def test_env_checker_passes():
    env = make(episode_periods=4, window=2)
    check_env(env.unwrapped)
    assert env.observation_space.shape == (12,)
    assert env.action_space.shape == (4,)


def test_same_seed_same_episode_other_seed_other_episode():
    actions = np.random.default_rng(0).uniform(-0.25, 0.25, (4, 4))
    options = {'scenario': 'random_walk', 'detector_noise': 0.01, 'plant': 'family'}
    first = rollout(make(**options), 5, 4, actions)
    again = rollout(make(**options), 5, 4, actions)
    other = rollout(make(**options), 6, 4, actions)
    np.testing.assert_array_equal(np.array(first[0]), np.array(again[0]))
    np.testing.assert_array_equal(first[1], again[1])
    assert [i['K'] for i in first[2]] == [i['K'] for i in again[2]]
    assert not np.array_equal(np.array(first[0]), np.array(other[0]))
    # the family plant and the walk were drawn from the seed
    assert first[2][0]['family_seed'] == again[2][0]['family_seed'] >= 0
    assert first[2][0]['family_seed'] != other[2][0]['family_seed']


def test_reward_is_the_measured_objective_and_info_holds_the_truth():
    env = make(scenario='constant', scenario_settings={'offset': 0.1}, initial='sech')
    obs, info = env.reset(seed=1)
    obs, reward, terminated, truncated, info = env.step(np.zeros(4))
    assert reward == pytest.approx(obs[0] / obs[1], rel=1e-6)   # float32 observation
    assert reward == pytest.approx(info['O_true'], rel=1e-12)   # no noise: O measured = true
    assert info['K'] == 0.1 and np.isfinite(info['O_star'])     # the nominal envelope
    assert info['round_trip'] == 20 and info['settled']
    assert not terminated and not truncated
    assert set(info['plant']) and info['plant'].shape == (len(PHYSICS_FIELDS),)


def test_delta_actions_move_the_angles_within_the_servo_limits_and_episodes_truncate():
    env = make(episode_periods=2, initial_angles=[0.0, 0.1, 0.2, 0.3], high=0.4)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(obs[2:], [0.0, 0.1, 0.2, 0.3], atol=1e-7)
    obs, *_, truncated, _ = env.step(np.array([1.0, -0.1, 0.25, 0.25]))
    # clipped to max_step 0.25 per period, then to the range's high end 0.4
    np.testing.assert_allclose(obs[2:], [0.25, 0.0, 0.4, 0.4], atol=1e-7)
    assert not truncated
    assert env.step(np.zeros(4))[3]


def test_absolute_actions_go_through_the_servo_limits():
    env = make(action='absolute', initial_angles=[0.0, 0.0, 0.0, 0.0])
    env.reset(seed=0)
    obs, *_ = env.step(np.array([1.0, -1.0, np.pi, 0.1]))
    np.testing.assert_allclose(obs[2:], [0.25, -0.25, 0.0, 0.1], atol=1e-7)


def test_a_lagging_servo_reaches_its_command_later():
    lagging = make(bench={'servo_lag': 6, 'slew_rate': 0.04}, initial_angles=[0.0] * 4)
    lagging.reset(seed=0)
    obs, _, _, _, info = lagging.step(np.full(4, 0.25))
    assert not info['settled']                 # 6 + 7 round trips > one period of 10
    assert obs[2] == pytest.approx(0.16, abs=1e-6)
    obs, _, _, _, info = lagging.step(np.zeros(4))
    assert info['settled'] and obs[2] == pytest.approx(0.25, abs=1e-6)


def test_vector_env_equals_single_envs_with_the_same_seeds_through_autoreset():
    B, steps, seed = 4, 5, 11     # 4: the thread-parallel kernel (PARALLEL_MIN_BATCH)
    options = {'episode_periods': 3, 'scenario': 'sinusoidal', 'detector_noise': 0.01}
    vector = gymnasium.make_vec(ENV, num_envs=B, solver=SMALL, **options)
    assert vector.metadata['autoreset_mode'] == gymnasium.vector.AutoresetMode.NEXT_STEP
    actions = np.random.default_rng(1).uniform(-0.25, 0.25, (steps, B, 4))
    obs, info = vector.reset(seed=seed)
    vec_obs, vec_rewards, vec_k = [obs], [], [info['K']]
    truncations = []
    for t in range(steps):
        obs, reward, terminated, truncated, info = vector.step(actions[t])
        vec_obs.append(obs)
        vec_rewards.append(reward)
        vec_k.append(info['K'])
        truncations.append(truncated)
        assert not terminated.any()
    assert [bool(t[0]) for t in truncations] == [False, False, True, False, False]
    for i in range(B):
        env = make(**options)
        obs, info = env.reset(seed=seed + i)
        np.testing.assert_array_equal(obs, vec_obs[0][i])
        for t in range(steps):
            if t == 3:    # the autoreset step: a new episode of the same generator
                obs, info = env.reset()
                reward = 0.0
            else:
                obs, reward, *_, info = env.step(actions[t, i])
            np.testing.assert_array_equal(obs, vec_obs[t + 1][i])
            assert reward == vec_rewards[t][i] and info['K'] == vec_k[t + 1][i]


def test_family_plants_are_drawn_per_reset_without_envelope_unless_a_source_gives_one():
    env = make(plant='family')
    _, first = env.reset(seed=2)
    _, second = env.reset()
    assert first['family_seed'] != second['family_seed']
    assert not np.array_equal(first['plant'], second['plant'])
    assert np.isnan(first['O_star'])
    expected = PlantFamily().draw(first['family_seed'], 0,
                                  CavityConfig(**SMALL))
    assert first['plant'][PHYSICS_FIELDS.index('pump')] == expected.pump

    def source(seed):
        return CavityConfig(**SMALL, pump=1.7), {'K': [-0.3, 0.3], 'O_star': [1.0, 2.0]}

    env = make(plant='family', plant_source=source, scenario='constant',
               scenario_settings={'offset': 0.0})
    _, info = env.reset(seed=2)
    assert info['O_star'] == pytest.approx(1.5) and info['plant'][3] == 1.7


@pytest.mark.parametrize('options, message', [
    ({'scenario': 'sinus'}, 'option scenario must be one of'),
    ({'scenario': 'sinusoidal', 'scenario_settings': {'amplitude': 0.5}}, 'outside the model'),
    ({'scenario': 'sinusoidal', 'scenario_settings': {'sigma': 0.1}}, 'takes'),
    ({'scenario': 'held', 'scenario_settings': {'offset': 0.1}}, 'takes no settings'),
    ({'plant': 'lab'}, 'option plant must be one of'),
    ({'plant': {'pumpp': 1.0}}, "plant sets ['pumpp']"),
    ({'plant': {'pump': -1.0}}, 'pump must be >= 0'),
    ({'solver': {'pump': 1.0}}, "solver sets ['pump']"),
    ({'detector_noise': 2.0}, 'detector_noise must be a number in [0, 0.5]'),
    ({'bench': 'servo-9'}, "unknown bench 'servo-9'"),
    ({'initial': 'cold'}, 'option initial must be one of'),
    ({'initial_angles': [0.0, 1.0]}, 'initial_angles'),
    ({'period': 0}, 'period must be an integer >= 1'),
    ({'action': 'relative'}, 'action must be one of'),
    ({'max_step': 0.0}, 'max_step must be > 0'),
    ({'plant': 'family', 'envelope': {'K': [0, 1], 'O_star': [1, 1]}}, 'applies to one plant'),
    ({'envelope': 'missing.npz'}, 'missing'),
    ({'windows': 3}, "unknown ModeLockedLaser option(s) ['windows']"),
])
def test_bad_options_stop_with_one_clear_line(options, message):
    with pytest.raises(ValueError) as err:
        make(**options)
    text = str(err.value)
    assert message in text and '\n' not in text


def test_bad_calls_stop_with_one_clear_line():
    env = make()
    with pytest.raises(ValueError, match='reset takes no options'):
        env.reset(seed=0, options={'K': 0.1})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r'action must have shape \(4,\)'):
        env.unwrapped.step(np.zeros(3))
    with pytest.raises(ValueError, match='action must be finite'):
        env.unwrapped.step(np.array([0.0, np.nan, 0.0, 0.0]))
    vector = gymnasium.make_vec(ENV, num_envs=2, solver=SMALL)
    with pytest.raises(ValueError, match='needs 2 seeds'):
        vector.reset(seed=[1, 2, 3])
    with pytest.raises(ValueError, match='option threads must be None or an integer'):
        gymnasium.make_vec(ENV, num_envs=2, solver=SMALL, threads=0)


def test_the_env_is_the_evaluation_closed_loop_period_for_period():
    """The same angles on the same laser and drift give dlmpc-evaluate's closed loop's
    measurements, bit for bit (ideal bench, no noise)."""
    from dlmpc_ros.control.step import ControlStep
    from dlmpc_ros.core.drift import make_scenario
    from dlmpc_ros.evaluation.closed_loop import run_closed_loop

    start = np.array([0.3, -0.2, 0.5, 0.1])
    deltas = np.random.default_rng(3).uniform(-0.25, 0.25, (4, 4))
    settings = {'amplitude': 0.25, 'period': 300.0}

    class Scripted:
        name = 'scripted'

        def __init__(self):
            self.measurements, self.angles = [], start.copy()

        def step(self, measurement, surrogate=None):
            self.measurements.append(measurement)
            if len(self.measurements) <= len(deltas):
                self.angles = self.angles + deltas[len(self.measurements) - 1]
            return ControlStep(angles=self.angles.copy(), mode='custom')

    controller = Scripted()
    run_closed_loop(controller, make_scenario('sinusoidal', **settings), 50, 10, start,
                    cavity_config=CavityConfig(**SMALL), initial='sech')
    env = make(scenario='sinusoidal', scenario_settings=settings, initial='sech',
               initial_angles=list(start))
    obs, _ = env.reset(seed=0)
    observations = [obs] + [env.step(d)[0] for d in deltas]
    np.testing.assert_array_equal(np.array(observations),
                                  np.array(controller.measurements, np.float32))
