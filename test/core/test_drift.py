import math

import numpy as np
import pytest

from dlmpc_ros.core.drift import DEFAULTS, SCENARIOS, make_scenario, parse_settings

R = np.arange(0, 50001, 7)


@pytest.mark.parametrize('name', [s for s in SCENARIOS if s != 'replay'])
def test_every_scenario_stays_in_model_range(name):
    k = make_scenario(name)(R)
    assert k.shape == R.shape and np.isfinite(k).all()
    assert k.min() >= -0.3 and k.max() <= 0.3


def test_sinusoidal_and_chirp_formulas():
    s = make_scenario('sinusoidal', offset=0.05, amplitude=0.1, period=400.0, phase=0.5)
    assert s(100) == pytest.approx(0.05 + 0.1 * np.sin(np.pi / 2 + 0.5))
    c = make_scenario('chirp', period=1000.0)
    assert c(1000) == pytest.approx(-0.075 + 0.175 * np.sin(0.5 * 49.0))
    assert c(0) == pytest.approx(-0.075)


def test_random_walk_is_seeded_order_independent_and_mean_reverting():
    a = make_scenario('random_walk', seed=5, sigma=0.08, correlation_time=500.0)
    b = make_scenario('random_walk', seed=5, sigma=0.08, correlation_time=500.0)
    late = b(150000)  # b jumps ahead first, a walks there in order
    path = a(np.arange(150001))
    assert path[-1] == late
    assert path[0] == 0.0
    assert abs(path.mean()) < 0.05
    assert 0.04 < path.std() < 0.12
    lag = 500
    corr = np.corrcoef(path[:-lag], path[lag:])[0, 1]
    assert 0.2 < corr < 0.6  # about exp(-1) at one correlation time
    other = make_scenario('random_walk', seed=6)(np.arange(1000))
    assert not np.allclose(other, path[:1000])


def test_steps_switch_at_their_times():
    s = make_scenario('steps', offset=0.0, times=[10, 20], values=[0.1, -0.2])
    np.testing.assert_allclose(s(np.array([0, 9, 10, 19, 20, 10**6])),
                               [0, 0, 0.1, 0.1, -0.2, -0.2])


def test_replay_interpolates_and_holds(tmp_path):
    path = tmp_path / 'k.csv'
    path.write_text('round_trip,K\n0,0.0\n100,0.2\n200,-0.1\n')
    s = make_scenario('replay', path=str(path))
    np.testing.assert_allclose(s(np.array([0, 50, 150, 500])), [0.0, 0.1, 0.05, -0.1])


@pytest.mark.parametrize('name, params, message', [
    ('sinusoidal', {'amplitude': 0.4}, 'outside the model range'),
    ('sinusoidal', {'period': 0.0}, 'period must be >= 1 round trip'),
    ('chirp', {'period': 5e-324}, 'period must be >= 1 round trip'),
    ('sinusoidal', {'phase': math.inf}, 'period and phase must be finite'),
    ('constant', {'offset': math.nan}, 'K levels must be finite'),
    ('random_walk', {'seed': math.inf}, 'seed must be an integer'),
    ('steps', {'times': [5, 3], 'values': [0.1, 0.2]}, 'increasing'),
    ('steps', {'times': [5], 'values': [0.1, 0.2]}, 'equally long'),
    ('random_walk', {'correlation_time': -1.0}, 'correlation_time'),
    ('replay', {'path': '/nonexistent.csv'}, 'cannot read'),
    ('replay', {}, 'set path'),
    ('constant', {'amplitude': 0.1}, 'takes'),
    ('wobble', {}, 'unknown drift scenario'),
])
def test_bad_scenarios_are_rejected_with_a_reason(name, params, message):
    with pytest.raises(ValueError, match=message):
        make_scenario(name, **params)


def test_bad_replay_file(tmp_path):
    path = tmp_path / 'bad.csv'
    path.write_text('0,0.1\n10,abc\n')
    with pytest.raises(ValueError, match='two numbers'):
        make_scenario('replay', path=str(path))
    path.write_text('0,0.1\n10,0.5\n')
    with pytest.raises(ValueError, match='outside the model range'):
        make_scenario('replay', path=str(path))


def test_parse_settings_types():
    parsed = parse_settings(['period=2000', 'seed=4', 'times=1,2.5', 'path=a.csv'])
    assert parsed == {'period': 2000.0, 'seed': 4, 'times': [1.0, 2.5], 'path': 'a.csv'}
    with pytest.raises(ValueError, match='KEY=VALUE'):
        parse_settings(['speed=3'])
    with pytest.raises(ValueError, match='bad value'):
        parse_settings(['sigma=lots'])
    with pytest.raises(ValueError, match='finite'):
        parse_settings(['offset=nan'])


def test_defaults_cover_every_scenario():
    assert set(DEFAULTS) == set(SCENARIOS)
