import math

from dlmpc_ros.interfaces import (ANGLE_FIELDS, STATE_FIELDS, RateLimitedLog, measured_state,
                                  usable_state, vector_fault)


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


def test_usable_state_drops_a_malformed_state_with_one_line_that_says_why():
    lines = []
    warn = RateLimitedLog(lines.append, clock=lambda: 0.0)
    good = [10.0, 3.0, 30.0, 0.1, 9.0, 1.0, 0.0, 0.0, 0.0, 0.0]
    assert len(good) == len(STATE_FIELDS) and usable_state(good, warn) and not lines
    assert not usable_state(good[:-1], warn)
    assert not usable_state([10.5, *good[1:]], warn)  # round trip is not a count
    assert len(lines) == 1 and '/laser/state' in lines[0] and 'expected 10 values' in lines[0]


def test_the_measured_state_of_a_laser_state_is_e_m_and_the_angles():
    data = [float(i) for i in range(len(STATE_FIELDS))]
    names = ('E', 'M', *ANGLE_FIELDS)
    assert measured_state(data) == [data[STATE_FIELDS.index(n)] for n in names]
    assert measured_state(data) == [1.0, 2.0, 6.0, 7.0, 8.0, 9.0]
