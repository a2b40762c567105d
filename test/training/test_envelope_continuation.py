"""Continuation in K over a plant's envelope: never lower, symmetric, finds a missed
optimum, cached apart from the base envelope."""

import json

import numpy as np
import pytest

from dlmpc_ros.core.angles import wrap_angles
from dlmpc_ros.core.plants import NOMINAL
from dlmpc_ros.learning.tables import load_baselines, write_npz
from dlmpc_ros.paths import models_dir
from dlmpc_ros.training import envelope as envelope_module
from dlmpc_ros.training.envelope import (ContinuationConfig, PlantEnvelopeConfig,
                                         cached_plant_envelope, check_symmetric,
                                         continue_envelope, envelope_paths, mirrored)
from dlmpc_ros.training.search import steady_scores

#: Short searches (cold runs of 200 round trips, 2 compass iterations).
QUICK = PlantEnvelopeConfig(k_points=3, neighbours=1, max_iterations=2, min_step=0.02, cap=100)
#: Three K points near 0, where neighbouring optima lie close together.
K = np.array([-0.02, 0.0, 0.02])


@pytest.fixture(scope='module')
def spoiled():
    """The nominal envelope at K with a poor state at K = 0 (alpha3 turned by 0.3 rad:
    O about 0.16 instead of 0.20), and the unspoiled O*."""
    tables = load_baselines(models_dir() / 'oracle.npz')
    nominal = mirrored(tables)
    at = np.searchsorted(np.round(nominal['K'], 9), np.round(K, 9))
    good = nominal['O_star'][at]
    angles = nominal['angles'][at].copy()
    angles[1] = wrap_angles(angles[1] + [0, 0, 0.3, 0])
    bad, _ = steady_scores(NOMINAL, angles[1:2], K[1:2], cap=2 * QUICK.cap, chunk=QUICK.chunk)
    o = good.copy()
    o[1] = bad[0]
    assert o[1] < 0.9 * good[1]
    return tables, {'K': K, 'O_star': o, 'angles': angles}, good


def test_continuation_finds_the_missed_optimum_and_never_lowers_the_envelope(spoiled):
    _, base, good = spoiled
    out = continue_envelope(NOMINAL, base, QUICK, ContinuationConfig(max_sweeps=2))
    check_symmetric(out)
    assert (out['O_star'] >= base['O_star']).all()
    assert out['O_star'][1] > 0.99 * good[1]        # found again from K = +-0.02
    assert out['moved_in_sweep'][1] == 1
    np.testing.assert_array_equal(out['O_star_base'], base['O_star'])
    unchanged = continue_envelope(NOMINAL, base, QUICK, ContinuationConfig(max_sweeps=0))
    np.testing.assert_array_equal(unchanged['O_star'], base['O_star'])
    with pytest.raises(ValueError, match='symmetric about 0'):
        continue_envelope(NOMINAL, {**base, 'K': K + 0.01}, QUICK)


def test_the_cached_envelope_is_the_continued_one_and_notes_what_moved(spoiled, tmp_path,
                                                                       monkeypatch):
    tables, base, good = spoiled
    cont = ContinuationConfig(max_sweeps=2)
    base_path, continued_path = envelope_paths(NOMINAL, tables, QUICK, cont, tmp_path)
    write_npz(base_path, base)                    # a cached base that missed K = 0
    env = cached_plant_envelope(NOMINAL, tables, QUICK, tmp_path, continuation=cont)
    assert env['O_star'][1] > 0.99 * good[1]
    note = json.loads(continued_path.with_suffix('.json').read_text())
    assert [m['K'] for m in note['moved']] == [0.0] and note['moved'][0]['ratio'] > 1.1
    assert note['continuation'] == cont.to_dict() and note['base'] == base_path.name
    monkeypatch.setattr(envelope_module, 'continue_envelope', None)   # read, not searched
    again = cached_plant_envelope(NOMINAL, tables, QUICK, tmp_path, continuation=cont)
    np.testing.assert_array_equal(again['O_star'], env['O_star'])
    alone = cached_plant_envelope(NOMINAL, tables, QUICK, tmp_path,
                                  continuation=ContinuationConfig(max_sweeps=0))
    np.testing.assert_array_equal(alone['O_star'], base['O_star'])
