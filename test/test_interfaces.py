import math

from dlmpc_ros.interfaces import ANGLE_FIELDS, RateLimitedLog, vector_fault


def test_vector_fault_names_the_problem():
    assert vector_fault([0.1, 0.2, 0.3, 0.4], ANGLE_FIELDS, 6.3) is None
    assert 'expected 4 values' in vector_fault([], ANGLE_FIELDS, 6.3)
    assert 'alpha2 is nan' in vector_fault([0, math.nan, 0, 0], ANGLE_FIELDS, 6.3)
    assert 'alpha1 is inf' in vector_fault([math.inf, 0, 0, 0], ANGLE_FIELDS, 6.3)
    assert 'outside' in vector_fault([0, 0, 1e308, 0], ANGLE_FIELDS, 6.3)


def test_rate_limited_log_counts_suppressed_lines():
    lines, now = [], [0.0]
    log = RateLimitedLog(lines.append, period=1.0, clock=lambda: now[0])
    assert log('a', 'first')
    assert not log('a', 'again')
    assert log('b', 'other key')
    now[0] = 1.5
    assert log('a', 'later')
    assert lines == ['first', 'other key', 'later (1 similar messages suppressed)']
