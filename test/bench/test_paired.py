"""bench/paired.py pairs the runs of two records, whichever tool wrote them."""

import json

import numpy as np
import pytest

from test.bench.test_variants_parse import _bench_module

paired = _bench_module('paired')


def _evaluate_run(plant: str, condition: str, seed: int, ratio: float) -> dict:
    return {'plant': plant, 'scenario': 'steps', 'condition': condition, 'seed': seed,
            'controller': 'dlmpc', 'metrics': {'oracle_ratio': ratio}}


def _variant_run(variant: str, plant: str, condition: str, seed: int, ratio: float) -> dict:
    return {'variant': variant, 'plant': plant, 'scenario': condition, 'seed': seed,
            'oracle_ratio': ratio}


def test_a_variants_record_pairs_with_an_evaluate_record_and_a_section_of_another(tmp_path):
    before = [_evaluate_run('family-5', 'walk-ideal', 1, 0.80),
              _evaluate_run('nominal', 'steps-servo3', 1, 0.90)]
    (tmp_path / 'before.json').write_text(json.dumps({'runs': before}))
    (tmp_path / 'nested.json').write_text(json.dumps(
        {'shipped': {'seed1': {'runs': before[:1]}, 'seed2': {'runs': before[1:]}}}))
    after = [_variant_run('a', '5', 'walk-ideal', 1, 0.83),
             _variant_run('a', 'nominal', 'steps-servo3', 1, 0.89),
             _variant_run('b', '5', 'walk-ideal', 1, 0.10)]
    (tmp_path / 'after.json').write_text(json.dumps({'runs': after}))
    a = paired.runs(paired.load_record(str(tmp_path / 'after.json')), 'dlmpc',
                    'oracle_ratio', 'a')
    assert a == {('family-5', 'walk-ideal', 1, 'dlmpc'): 0.83,
                 ('nominal', 'steps-servo3', 1, 'dlmpc'): 0.89}
    for spec in (str(tmp_path / 'before.json'),
                 f"{tmp_path / 'nested.json'}:shipped.seed1,shipped.seed2"):
        b = paired.runs(paired.load_record(spec), 'dlmpc', 'oracle_ratio')
        result = paired.paired(b, a)
        assert result['runs'] == 2
        assert result['difference'] == pytest.approx(0.01)
        np.testing.assert_allclose(sorted(result['diff']), [-0.01, 0.03])
    with pytest.raises(ValueError, match=r"variants \['a', 'b'\]: choose one"):
        paired.runs(paired.load_record(str(tmp_path / 'after.json')), 'dlmpc', 'oracle_ratio')
    with pytest.raises(ValueError, match="no section 'shipped.seed3'"):
        paired.load_record(f"{tmp_path / 'nested.json'}:shipped.seed3")
    with pytest.raises(ValueError, match='share no run'):
        paired.paired(b, paired.runs(paired.load_record(str(tmp_path / 'after.json')),
                                     'esc', 'oracle_ratio', 'a'))
