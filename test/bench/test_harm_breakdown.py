"""``bench/harm_breakdown.py``: a do-no-harm miss's lost O split by what the DL-MPC did."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dlmpc_ros.control.step import MODES
from test.bench.test_variants_parse import _bench_module


def _record(path, o, k, control_round_trip=None, mode=None, estimate=None):
    path.mkdir(parents=True)
    n = len(o)
    crt = np.zeros(0) if control_round_trip is None else control_round_trip
    np.savez(path / 'record.npz', round_trip=np.arange(n), O=np.asarray(o, float),
             K=np.asarray(k, float), control_round_trip=crt,
             mode=np.zeros(0, int) if mode is None else np.asarray(mode),
             surrogate=np.zeros(0) if estimate is None else np.asarray(estimate, float))


def test_a_miss_is_split_into_scanning_opposite_side_and_the_rest(tmp_path):
    k = np.full(8, -0.2)                                  # K < 0: the estimate wants s < 0
    decisions = np.array([0, 2, 4, 6])                    # one decision each 2 round trips
    modes = [MODES.index(m) for m in ('acquire', 'track', 'plan', 'track')]
    _record(tmp_path / 'family-1' / 'walk-ideal-s1-dlmpc', [0.0, 0.0, .1, .1, .2, .2, .3, .3], k,
            decisions, modes, [np.nan, 0.1, -0.1, -0.1])  # opposite side while tracking at 2-3
    _record(tmp_path / 'family-1' / 'walk-ideal-s1-passive', [0.3] * 8, k)
    _record(tmp_path / 'family-1' / 'walk-ideal-s1-fixed_best', [0.2] * 8, k)
    runs = [{'plant': 'family-1', 'condition': 'walk-ideal', 'seed': 1, 'controller': c,
             'metrics': {'oracle_ratio': r}}
            for c, r in (('dlmpc', 0.5), ('passive', 0.9), ('fixed_best', 0.6))]
    (tmp_path / 'metrics.json').write_text(json.dumps({'runs': runs}))
    (row,) = _bench_module('harm_breakdown').breakdown(tmp_path, 0.01)
    assert row['held'] == 'passive'
    assert row['scanning'] == pytest.approx((0.3 + 0.3) / 8)
    assert row['opposite'] == pytest.approx((0.2 + 0.2) / 8)
    assert row['else'] == pytest.approx((0.1 + 0.1 + 0 + 0) / 8)
    assert row['scanning_share'] == pytest.approx(0.25) and row['opposite_share'] == 0.25
    runs[0]['metrics']['oracle_ratio'] = 0.895                  # within 0.01: no miss
    (tmp_path / 'metrics.json').write_text(json.dumps({'runs': runs}))
    assert _bench_module('harm_breakdown').breakdown(tmp_path, 0.01) == []


def test_against_the_envelope_every_run_is_split_and_the_parts_add_up(tmp_path):
    """``--envelope``: each DL-MPC run of the chosen conditions, its lost share of the
    nominal cavity's envelope O*(K) split into the same parts, which add up to 1 - the
    ratio of the run's O to O*."""
    from dlmpc_ros.learning.tables import envelope_objective, load_baselines
    k = np.full(8, -0.2)
    modes = [MODES.index(m) for m in ('acquire', 'track', 'plan', 'track')]
    o = [0.0, 0.0, .1, .1, .2, .2, .15, .15]
    for condition in ('steps-ideal', 'walk-ideal'):
        _record(tmp_path / 'nominal' / f'{condition}-s1-dlmpc', o, k, np.array([0, 2, 4, 6]),
                modes, [np.nan, 0.1, -0.1, -0.1])
    runs = [{'plant': 'nominal', 'condition': c, 'seed': 1, 'controller': 'dlmpc',
             'metrics': {'oracle_ratio': 0.5}} for c in ('steps-ideal', 'walk-ideal')]
    (tmp_path / 'metrics.json').write_text(json.dumps({'runs': runs}))
    (row,) = _bench_module('harm_breakdown').envelope_breakdown(tmp_path, ['steps-ideal'])
    tables = load_baselines(Path(__file__).resolve().parents[2] / 'models' / 'oracle.npz')
    best = envelope_objective(tables, k)
    assert row['condition'] == 'steps-ideal'
    assert row['scanning'] == pytest.approx(best[:2].sum() / best.sum())
    assert row['opposite'] == pytest.approx((best[2:4].sum() - 0.2) / best.sum())
    assert row['after_jump'] == 0.0                             # K never steps here
    assert row['scanning'] + row['opposite'] + row['else'] == pytest.approx(
        1 - sum(o) / best.sum())


def test_the_round_trips_after_a_step_of_k_are_a_part_of_their_own(tmp_path):
    """K steps from -0.2 to +0.2 at round trip 4; with ``after_jump`` 2, the O lost while
    tracking on the right side in round trips 4-5 is counted apart, the rest as before."""
    _record(tmp_path / 'r', [0.0] * 8, [-0.2] * 4 + [0.2] * 4, np.array([0]),
            [MODES.index('track')], [0.1])
    d = np.load(tmp_path / 'r' / 'record.npz')
    lost = np.arange(1.0, 9.0)
    parts = _bench_module('harm_breakdown')._parts(d, lost, 1.0, after_jump=2)
    assert parts['opposite'] == pytest.approx(1 + 2 + 3 + 4)   # estimate > 0 while K < 0
    assert parts['after_jump'] == pytest.approx(5 + 6)
    assert parts['else'] == pytest.approx(7 + 8)
    assert _bench_module('harm_breakdown')._parts(d, lost, 1.0)['else'] == pytest.approx(26)
