"""A control period's measurement from the states of its round trips."""

import numpy as np
import pytest

from dlmpc_ros.control.step import PeriodMeasurement, period_measurement

ANGLES = [0.1, -0.2, 0.3, 0.4]
OTHER = [0.2, -0.2, 0.3, 0.4]


def _state(e: float, m: float, angles=ANGLES) -> np.ndarray:
    return np.array([e, m, *angles])


def _decide(periods, round_trip, state, command=None):
    """Add a state; if a decision is due, give it ``command`` (default: hold)."""
    measurement = periods.add(round_trip, state)
    if measurement is not None:
        periods.command(measurement[2:] if command is None else command)
    return measurement


def test_one_round_trip_gives_the_periods_own_state():
    periods = PeriodMeasurement(period=5, round_trips=1)
    assert [periods.wanted(r) for r in range(1, 6)] == [False] * 4 + [True]
    assert _decide(periods, 5, _state(2.0, 3.0)) is not None
    assert [periods.wanted(r) for r in range(6, 11)] == [False] * 4 + [True]
    np.testing.assert_array_equal(_decide(periods, 10, _state(4.0, 5.0)), _state(4.0, 5.0))


def test_the_mean_of_the_latest_round_trips_at_the_periods_angles():
    periods = PeriodMeasurement(period=10, round_trips=3, tolerance=0.0)
    assert [r for r in range(1, 11) if periods.wanted(r)] == [8, 9, 10]
    for r, e in ((8, 1.0), (9, 2.0)):
        assert periods.add(r, _state(e, 2 * e)) is None
    np.testing.assert_allclose(_decide(periods, 10, _state(6.0, 12.0), ANGLES),
                               _state(3.0, 6.0))
    # a state away from the command (a bump) delays the decision until the readings
    # have been at the command for 3 round trips; only the states at it count
    periods.add(18, _state(1.0, 1.0, OTHER))
    periods.add(19, _state(2.0, 4.0))
    assert periods.add(20, _state(4.0, 8.0)) is None
    np.testing.assert_allclose(periods.add(21, _state(6.0, 12.0)), _state(4.0, 8.0))


def test_a_gap_leaves_out_what_is_older_than_the_window():
    periods = PeriodMeasurement(period=10, round_trips=3)
    periods.add(7, _state(100.0, 100.0))  # not wanted by a caller, and too old
    periods.add(9, _state(2.0, 2.0))       # round trip 8 never came
    np.testing.assert_allclose(periods.add(10, _state(4.0, 4.0)), _state(3.0, 3.0))
    # the decision's round trip again: no second decision before its command
    assert periods.add(10, _state(6.0, 6.0)) is None
    # a new run counts its round trips from 1 again: nothing of the old run is averaged
    periods.add(9, _state(1.0, 1.0))
    np.testing.assert_allclose(periods.add(10, _state(3.0, 3.0)), _state(2.0, 2.0))


def test_a_decision_waits_until_the_servos_reach_the_command():
    periods = PeriodMeasurement(period=10, round_trips=3, tolerance=0.01, timeout=50)
    for r in range(8, 11):
        measurement = periods.add(r, _state(1.0, 1.0))
    periods.command(OTHER)                          # alpha1 moves by 0.1 rad
    assert all(periods.wanted(r) for r in range(11, 15))  # its settle time is measured
    alpha1 = [0.1, 0.1, 0.1, 0.13, 0.16, 0.19, 0.195, 0.2, 0.2]  # lag 3, slew 0.03
    for r, a in zip(range(11, 20), alpha1):
        angles = [a, *OTHER[1:]]
        measurement = periods.add(r, _state(float(r), 1.0, angles))
        assert measurement is None
    # settled (within 0.01) from round trip 17 on: due once 3 settled states are in
    measurement = periods.add(20, _state(20.0, 1.0, [0.2004, *OTHER[1:]]))
    np.testing.assert_allclose(measurement[:2], [(18 + 19 + 20) / 3, 1.0])
    np.testing.assert_allclose(measurement[2:], OTHER)  # the median reported angles
    assert periods.settled and periods.settle_round_trips == 7


def test_a_command_that_only_moves_the_servos_on_is_decided_on_once_reached():
    """measure=False (the controller is travelling): no average is waited for, the
    decision comes with the first settled state, never before the period."""
    alpha1 = [0.1, 0.1, 0.1, 0.13, 0.16, 0.19, 0.195, 0.2, 0.2]  # settled from 17 on
    due = {}
    for measure in (True, False):
        periods = PeriodMeasurement(period=5, round_trips=3, tolerance=0.01, timeout=50)
        for r in range(8, 11):
            periods.add(r, _state(1.0, 1.0))
        periods.command(OTHER, measure=measure)
        for r, a in zip(range(11, 21), [*alpha1, 0.2]):
            if periods.add(r, _state(float(r), 1.0, [a, *OTHER[1:]])) is not None:
                due[measure] = r
                break
    assert due == {True: 19, False: 17}
    # with servos that arrive at once it changes nothing: still one decision per period
    periods = PeriodMeasurement(period=10, round_trips=3)
    periods.add(10, _state(1.0, 1.0))
    periods.command(OTHER, measure=False)
    assert [r for r in range(11, 21) if periods.add(r, _state(1.0, 1.0, OTHER)) is not None] \
        == [20]


def test_a_command_not_reached_is_decided_on_at_the_timeout():
    periods = PeriodMeasurement(period=10, round_trips=3, tolerance=0.001, timeout=30)
    for r in range(8, 11):
        periods.add(r, _state(1.0, 1.0))
    periods.command(OTHER)
    for r in range(11, 40):  # stuck 0.05 short of the command
        assert periods.add(r, _state(float(r), 1.0, [0.15, *OTHER[1:]])) is None
    measurement = periods.add(40, _state(40.0, 1.0, [0.15, *OTHER[1:]]))
    np.testing.assert_allclose(measurement, _state(40.0, 1.0, [0.15, *OTHER[1:]]))
    assert not periods.settled and periods.settle_round_trips is None


def test_with_unknown_commands_the_trailing_states_at_one_angle_count():
    periods = PeriodMeasurement(period=10, round_trips=3, tolerance=0.0)
    for r in range(8, 11):
        periods.add(r, _state(1.0, 1.0))
    periods.command(None)
    periods.add(18, _state(5.0, 5.0))
    periods.add(19, _state(2.0, 2.0, OTHER))
    np.testing.assert_allclose(periods.add(20, _state(4.0, 4.0, OTHER)),
                               _state(3.0, 3.0, OTHER))


@pytest.mark.parametrize('kwargs', [{'period': 0}, {'period': 10, 'round_trips': 0},
                                    {'period': 10, 'round_trips': 2.5},
                                    {'period': True}, {'period': 10, 'timeout': 0}])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError, match='integer >= 1'):
        PeriodMeasurement(**kwargs)
    with pytest.raises(ValueError, match='tolerance'):
        PeriodMeasurement(10, tolerance=-1.0)


def test_a_state_array_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=r'\(n >= 1, 6\)'):
        period_measurement(np.zeros((0, 6)))
    with pytest.raises(ValueError, match=r'\(n >= 1, 6\)'):
        period_measurement(np.zeros((2, 5)))
