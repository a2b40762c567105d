"""The mirrored envelope and a plant's envelope, cached; family draws that mode-lock."""

import numpy as np
import pytest

from dlmpc_ros.core.plants import NOMINAL, PlantFamily
from dlmpc_ros.learning.tables import load_baselines
from dlmpc_ros.paths import models_dir
from dlmpc_ros.training.envelope import (PlantEnvelopeConfig, cached_plant_envelope,
                                         check_symmetric, draw_plant, mirrored,
                                         plant_envelope)

TINY = PlantEnvelopeConfig(k_points=5, neighbours=1, max_iterations=2, min_step=0.04, cap=200)


def test_the_mirror_takes_the_better_twin_and_makes_the_envelope_symmetric():
    k = np.linspace(-0.3, 0.3, 5)
    env = {'K': k, 'O_star': np.array([0.20, 0.21, 0.22, 0.25, 0.19]),
           'angles': np.arange(20.0).reshape(5, 4) / 10}
    out = mirrored(env)
    np.testing.assert_allclose(out['O_star'], [0.20, 0.25, 0.22, 0.25, 0.20])
    assert out['from_mirror'].tolist() == [False, True, False, False, True]
    np.testing.assert_allclose(np.sin(2 * out['angles'][1]),
                               np.sin(2 * (env['angles'][3] + [np.pi / 2, np.pi / 2, 0,
                                                               np.pi / 2])))
    check_symmetric(out)
    with pytest.raises(ValueError, match='not symmetric'):
        check_symmetric(env)
    with pytest.raises(ValueError, match='symmetric about 0'):
        mirrored({**env, 'K': k + 0.01})


def test_a_plant_envelope_is_symmetric_locked_and_cached(tmp_path):
    tables = load_baselines(models_dir() / 'oracle.npz')
    env = cached_plant_envelope(NOMINAL, tables, TINY, tmp_path)
    check_symmetric(env)
    assert env['K'].size == 5 and bool(env['mode_locks'])
    nominal = mirrored(tables)
    at = np.searchsorted(np.round(nominal['K'], 9), np.round(env['K'], 9))
    assert (np.abs(env['O_star'] / nominal['O_star'][at] - 1) < 0.02).all()
    cached = list((tmp_path / 'envelopes').glob('*.npz'))
    assert len(cached) == 1 and cached[0].with_suffix('.json').is_file()
    again = cached_plant_envelope(NOMINAL, tables, TINY, tmp_path)  # read, not searched
    np.testing.assert_array_equal(again['O_star'], env['O_star'])
    weaker = plant_envelope(NOMINAL.__class__(pump=1.55), tables, TINY)
    assert weaker['O_star'].mean() < env['O_star'].mean()


def test_family_draws_that_cannot_mode_lock_are_redrawn_or_refused(tmp_path):
    tables = load_baselines(models_dir() / 'oracle.npz')
    plant, attempt = draw_plant(PlantFamily(), 3, tables, TINY, tmp_path)
    assert attempt >= 0 and plant == PlantFamily().draw(3, attempt)
    assert draw_plant(PlantFamily(), 3, tables, TINY, tmp_path) == (plant, attempt)
    dead = PlantFamily(pump_factor=(0.3, 0.3))  # far below threshold: no pulse anywhere
    with pytest.raises(ValueError, match='mode-locks'):
        draw_plant(dead, 1, tables, PlantEnvelopeConfig(k_points=3, neighbours=1, cap=100),
                   tmp_path, max_draws=2)
