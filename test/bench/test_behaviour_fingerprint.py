"""bench/behaviour_fingerprint.py: an unreadable record stops it before any run."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'bench'))
import behaviour_fingerprint  # noqa: E402


def test_an_unreadable_record_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / 'before.json'
    bad.write_text('{not json')
    with pytest.raises(SystemExit) as stop:
        behaviour_fingerprint.main(['--check', str(bad)])
    assert stop.value.code == 2
    assert 'cannot read' in capsys.readouterr().err


def test_the_cases_cover_both_strategies_and_the_stress_benches():
    from dlmpc_ros.evaluation.suites import stress_conditions
    names = stress_conditions()
    assert {c[1] for c in behaviour_fingerprint.CASES} == {'dlmpc', 'dlmpc_paper'}
    assert all(c[3] in names for c in behaviour_fingerprint.CASES)
    assert {c[3].split('-')[1] for c in behaviour_fingerprint.CASES} >= {'ideal', 'servo3',
                                                                          'servo6', 'noise1'}
