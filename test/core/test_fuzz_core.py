"""Property-based fuzzing of the core without ROS: the cavity and the drift scenarios.

Properties: any value either is refused with a ValueError that names the parameter, or
gives a model that runs (a cavity whose observables are finite or flagged, a scenario
whose K is finite and inside the model range) in bounded time.
"""

from __future__ import annotations

import math
import time
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from dlmpc_ros.core.cavity import Cavity
from dlmpc_ros.core.config import CavityConfig
from dlmpc_ros.core.drift import DEFAULTS, K_MAX, K_MIN, make_scenario
from dlmpc_ros.core.schemes import SCHEMES
from test.strategies import any_float, any_int, finite_float

FIELDS = {f.name: f.type for f in fields(CavityConfig)}
#: Round trips a fuzzed cavity runs; its grid is kept small so that examples stay fast.
ROUND_TRIPS = 5


def _value(name: str):
    if name in ('points', 'steps_per_round_trip'):
        return st.one_of(any_int(), any_float(), st.booleans())
    if name == 'scheme':
        return st.one_of(st.sampled_from(SCHEMES), st.text(max_size=8), any_int())
    return st.one_of(any_float(), any_int(), st.booleans(), st.text(max_size=3))


@given(name=st.sampled_from(sorted(FIELDS)), data=st.data())
def test_a_cavity_parameter_is_refused_by_name_or_runs(name, data):
    value = data.draw(_value(name))
    small = {'points': 64, 'steps_per_round_trip': 8}
    try:
        config = CavityConfig(**{**small, name: value})
    except ValueError as err:
        assert name in str(err)
        return
    if config.points * config.steps_per_round_trip > 2 ** 17:  # a valid but slow grid
        config = CavityConfig(**{**config.to_dict(), **small})
    angles = data.draw(st.lists(finite_float(10.0), min_size=4, max_size=4))
    k = data.draw(st.floats(K_MIN, K_MAX))
    cavity = Cavity(config, angles=np.array(angles), birefringence=k)
    Cavity(CavityConfig(**small, scheme=config.scheme)).step()  # compiled once, not timed
    started = time.perf_counter()
    for _ in range(ROUND_TRIPS):
        result = cavity.step()
        if not result.finite[0]:  # blown up: flagged, never a crash (laser_sim resets)
            assert math.isnan(result.O[0])
            cavity.reset()
            continue
        for value in (result.E[0], result.M[0], result.O[0], result.energy[0]):
            assert math.isfinite(value)
        assert result.O[0] >= 0.0 and result.E[0] >= 0.0
    assert time.perf_counter() - started < 30.0


SCENARIO_NAMES = sorted(n for n in DEFAULTS if n != 'replay')


def _setting(key: str):
    if key in ('times', 'values'):
        return st.lists(any_float(), max_size=5)
    if key == 'seed':
        return st.one_of(any_int(), any_float())
    return st.one_of(any_float(), any_int())


@given(name=st.sampled_from(SCENARIO_NAMES), data=st.data())
def test_a_drift_setting_is_refused_or_gives_k_in_range(name, data):
    keys = data.draw(st.sets(st.sampled_from(sorted(DEFAULTS[name])), max_size=3))
    settings = {k: data.draw(_setting(k)) for k in keys}
    try:
        scenario = make_scenario(name, **settings)
    except (ValueError, OverflowError, TypeError) as err:
        assert isinstance(err, ValueError), f'{type(err).__name__}: {err}'
        return
    # round trips in increasing order, jumps of up to a million (drift_injector's bound)
    steps = data.draw(st.lists(st.integers(0, 10 ** 6), min_size=1, max_size=6))
    round_trips = np.cumsum(steps)
    started = time.perf_counter()
    for r in round_trips:
        k = scenario(int(r))
        assert math.isfinite(k) and K_MIN <= k <= K_MAX, (settings, r, k)
    assert time.perf_counter() - started < 30.0


@pytest.mark.parametrize('name', SCENARIO_NAMES)
def test_a_scenario_answers_for_any_round_trip_array(name):
    scenario = make_scenario(name)
    k = scenario(np.array([0, 1, 5, 10 ** 6]))
    assert np.isfinite(k).all() and ((k >= K_MIN) & (k <= K_MAX)).all()
