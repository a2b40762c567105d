"""A control period's measurement from the states of its round trips."""

import numpy as np
import pytest

from dlmpc_ros.control.period_measurement import PeriodMeasurement, period_measurement

ANGLES = [0.1, -0.2, 0.3, 0.4]
OTHER = [0.2, -0.2, 0.3, 0.4]


def _state(e: float, m: float, angles=ANGLES) -> np.ndarray:
    return np.array([e, m, *angles])


def test_one_round_trip_gives_the_periods_own_state():
    periods = PeriodMeasurement(period=5, round_trips=1)
    assert [periods.wanted(r) for r in range(1, 11)] == [False] * 4 + [True] + \
        [False] * 4 + [True]
    assert periods.add(5, _state(2.0, 3.0)) is not None
    np.testing.assert_array_equal(periods.add(10, _state(4.0, 5.0)), _state(4.0, 5.0))


def test_the_mean_of_the_latest_round_trips_at_the_periods_angles():
    periods = PeriodMeasurement(period=10, round_trips=3)
    assert [r for r in range(1, 21) if periods.wanted(r)] == [8, 9, 10, 18, 19, 20]
    for r, e in ((8, 1.0), (9, 2.0)):
        assert periods.add(r, _state(e, 2 * e)) is None
    np.testing.assert_allclose(periods.add(10, _state(6.0, 12.0)), _state(3.0, 6.0))
    # an angle change inside the window: only the states at the period's angles count
    periods.add(18, _state(1.0, 1.0, OTHER))
    periods.add(19, _state(2.0, 4.0))
    np.testing.assert_allclose(periods.add(20, _state(4.0, 8.0)), _state(3.0, 6.0))


def test_a_gap_leaves_out_what_is_older_than_the_window():
    periods = PeriodMeasurement(period=10, round_trips=3)
    periods.add(7, _state(100.0, 100.0))  # not wanted by a caller, and too old
    periods.add(9, _state(2.0, 2.0))       # round trip 8 never came
    np.testing.assert_allclose(periods.add(10, _state(4.0, 4.0)), _state(3.0, 3.0))
    # the same round trip again replaces its state
    np.testing.assert_allclose(periods.add(10, _state(6.0, 6.0)), _state(4.0, 4.0))
    # a new run counts its round trips from 1 again: nothing of the old run is averaged
    periods.add(9, _state(1.0, 1.0))
    np.testing.assert_allclose(periods.add(10, _state(3.0, 3.0)), _state(2.0, 2.0))


@pytest.mark.parametrize('kwargs', [{'period': 0}, {'period': 10, 'round_trips': 0},
                                    {'period': 10, 'round_trips': 2.5},
                                    {'period': True}])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(ValueError, match='integer >= 1'):
        PeriodMeasurement(**kwargs)


def test_a_state_array_of_the_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=r'\(n >= 1, 6\)'):
        period_measurement(np.zeros((0, 6)))
    with pytest.raises(ValueError, match=r'\(n >= 1, 6\)'):
        period_measurement(np.zeros((2, 5)))
