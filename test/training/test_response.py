"""The steady-response data over the plant family and the pairs that train the predictor."""

import numpy as np
import pytest

from dlmpc_ros.learning.curve import load_curve
from dlmpc_ros.paths import models_dir
from dlmpc_ros.training.response import (COLUMNS, LOST, ResponseConfig, ResponseTask,
                                        response_rows)
from dlmpc_ros.training.stages.response import PairRule, profile_pairs, profiles


def test_rows_step_the_rotation_both_ways_from_the_settled_curve_point():
    grid, angles, _ = load_curve(models_dir() / 'track_curve.npz')
    cfg = ResponseConfig(plants=1, k_values=(-0.2,), offsets=(0.0, 0.04), steps=2, hold=20,
                         settle=60, step=0.05)
    rows = response_rows(ResponseTask(cfg, (2001,), grid, angles))
    data = dict(zip(COLUMNS, rows.T))
    assert rows.shape == (2 * (2 * 2 + 1), len(COLUMNS))   # two curve points, 5 rotations
    assert set(data['plant']) == {2001} and set(data['K']) == {-0.2}
    assert sorted(set(np.round(data['u'], 6))) == [-0.2, -0.16]
    assert sorted(np.round(data['theta'][data['u'] == -0.2], 6)) == [-0.1, -0.05, 0.0,
                                                                        0.05, 0.1]
    assert np.all(data['E'] > 0) and np.all(data['M'] >= 1)
    assert ResponseConfig().first_seed > 1000  # none of the evaluation's plants (1-8, 101-108)


def test_pairs_hold_the_change_of_log_o_and_lost_where_the_pulse_goes():
    theta = np.round(np.arange(-4, 5) * 0.05, 6)
    objective = np.array([0.001, 0.15, 0.18, 0.19, 0.2, 0.21, 0.2, 0.19, 0.17])
    energy = 3.0 * np.ones(9)
    profile = {'plant': np.zeros(9), 'K': -0.2 * np.ones(9), 'u': -0.2 * np.ones(9),
               'theta': theta, 'E': energy, 'M': energy / objective}
    x, y = profile_pairs(profile, PairRule(trust=0.1, pulse_fraction=0.3))
    assert x.shape[1] == 5 and x.shape[0] == y.size
    lookup = {(round(a, 6), round(a + d, 6)): t for a, d, t in zip(x[:, 1], x[:, 4], y)}
    assert lookup[(0.0, 0.05)] == pytest.approx(np.log(0.21 / 0.2))
    assert lookup[(0.0, 0.0)] == 0.0
    assert lookup[(-0.15, -0.2)] == LOST       # into the state without a pulse
    assert (-0.2, -0.15) not in lookup         # no pair starts without a pulse
    assert (0.0, 0.15) not in lookup           # beyond the trust radius
    assert np.all(y >= LOST)


def test_profiles_group_rows_by_plant_k_and_curve_point():
    data = {'plant': np.array([1, 1, 2, 1]), 'K': np.array([-0.2, -0.2, -0.2, -0.2]),
            'u': np.array([-0.2, -0.2, -0.2, -0.16]), 'theta': np.array([0.1, -0.1, 0.0, 0.0]),
            'E': np.ones(4), 'M': np.ones(4)}
    groups = profiles(data)
    assert sorted(g['theta'].size for g in groups) == [1, 1, 2]
    two = next(g for g in groups if g['theta'].size == 2)
    assert list(two['theta']) == [-0.1, 0.1]     # sorted by rotation
