"""One preset table for every caller, and the run specification."""

import pytest

from dlmpc_ros.evaluation.presets import (CHECK_CASES, PRESETS, preset_scenario,
                                          preset_settings, run_settings)
from dlmpc_ros.evaluation.runs import RunSpec, setting_strings


def test_presets_keep_k_in_range_and_take_only_their_own_settings():
    for name in PRESETS:
        scenario = preset_scenario(name, seed=1)
        k = scenario(list(range(0, 20001, 50)))
        assert (abs(k) <= 0.3 + 1e-12).all(), name
    assert preset_settings('sinusoidal', {'amplitude': 0.1, 'sigma': 0.5}) == {
        'amplitude': 0.1, 'period': 10000.0}
    with pytest.raises(ValueError, match='outside the model range'):
        preset_settings('sinusoidal', {'amplitude': 0.5})


def test_the_random_walk_follows_the_run_seed_unless_it_has_its_own():
    assert run_settings('random_walk', 4)['seed'] == 4
    assert run_settings('random_walk', 4, {'seed': 11})['seed'] == 11
    assert 'seed' not in run_settings('chirp', 4)
    a, b = preset_scenario('random_walk', 1), preset_scenario('random_walk', 2)
    assert a(5000) != b(5000)
    assert set(CHECK_CASES) >= {'random_walk_11', 'random_walk_12'}


def test_run_spec_checks_its_fields_and_describes_its_run():
    spec = RunSpec('steps', 3, 'esc', round_trips=100)
    meta = spec.meta()
    assert meta['settings'] == PRESETS['steps'] and meta['mode'] == 'fast'
    assert len(meta['initial_angles']) == 4
    assert setting_strings(meta['settings']) == ['times=5000.0,10000.0,15000.0',
                                                 'values=0.2,-0.2,0.1']
    for bad in ({'scenario': 'nope'}, {'mode': 'slow'}, {'round_trips': 0},
                {'max_step': 0.0}):
        with pytest.raises(ValueError):
            RunSpec(**{'scenario': 'steps', 'seed': 1, 'controller': 'esc', **bad})
