"""The levels of /diagnostics, from what the nodes count (no ROS)."""

import math

import pytest

from dlmpc_ros.interfaces import RateLimitedLog
from dlmpc_ros.health import (ERROR, FIRST_INPUT_GRACE, OK, SILENT_AFTER, WARN, CounterWindow,
                              Findings, Health, controller_health, laser_health)

COUNTS = {'commands_received': 5, 'birefringence_received': 50, 'messages_rejected': 0,
          'resets': 0, 'lockstep_timeouts': 0}


def test_an_input_is_waited_for_then_judged_by_its_age():
    f = Findings()
    f.input('/laser/state', None, started=0.0, now=FIRST_INPUT_GRACE / 2)
    assert f.health('ok').level == OK  # still starting
    f.input('/laser/state', None, started=0.0, now=FIRST_INPUT_GRACE + 1)
    assert f.health('ok').level == WARN and 'waiting for /laser/state' in f.health('').message
    f = Findings()
    f.input('/laser/state', 10.0, started=0.0, now=10.0 + SILENT_AFTER / 2)
    assert f.health('fine').level == OK
    f.input('/laser/state', 10.0, started=0.0, now=10.0 + SILENT_AFTER + 1)
    assert f.health('fine').level == ERROR
    quiet = Findings()
    quiet.input('/estimator/birefringence', 1.0, 0.0, 9.0, silent_level=WARN)
    assert quiet.health('').level == WARN and 'for 8.0 s' in quiet.health('').message


def test_the_laser_warns_about_what_happened_since_the_last_report_only():
    window, drops = CounterWindow(), CounterWindow()
    log = RateLimitedLog(lambda text: None)
    for _ in range(3):
        log.dropped('/laser/angles_cmd', 'expected 4 values')
    health = laser_health(Findings(), window, 100, 500.0, COUNTS, running=True)
    assert health.level == OK and health.message == 'round trip 100 at 500 round trips/s'
    assert health.value('commands_received') == '5' and health.value('rate_hz') == '500'
    f = Findings()
    f.new_drops(drops, log)
    health = laser_health(f, window, 200, 500.0, {**COUNTS, 'resets': 1}, running=True)
    assert health.level == WARN
    assert '1 field resets' in health.message and 'expected 4 values' in health.message
    f = Findings()
    f.new_drops(drops, log)
    health = laser_health(f, window, 300, 500.0, {**COUNTS, 'resets': 1}, running=True)
    assert health.level == OK and health.value('messages_dropped') == '3'
    stopped = laser_health(Findings(), window, 300, 0.0, COUNTS, running=False)
    assert stopped.level == ERROR and 'stopped at round trip 300' in stopped.message


def test_a_controller_below_its_lock_threshold_warns():
    locked = controller_health(Findings(), 'track', 0.2, 0.1, 40, 0.0, uses_estimator=True)
    assert locked.level == OK and locked.value('locked') == 'true'
    lost = controller_health(Findings(), 'acquire', 0.01, 0.1, 41, 3.0, uses_estimator=True)
    assert lost.level == WARN and 'not mode-locked' in lost.message
    assert lost.value('estimate_age_periods') == '3'
    nan = controller_health(Findings(), 'hold', math.nan, 0.1, 1, None, uses_estimator=False)
    assert nan.level == WARN and 'estimate_age_periods' not in dict(nan.values)
    fresh = controller_health(Findings(), None, None, None, 0, None, uses_estimator=False)
    assert fresh.level == OK and fresh.message == 'waiting for the first period'
    assert not any(key.startswith('modes_last') for key, _ in fresh.values)
    scanning = controller_health(Findings(), 'track', 0.2, 0.1, 4, None, uses_estimator=False,
                                 recent_modes=['acquire', 'track', 'acquire', 'inner'])
    assert scanning.value('modes_last_4_decisions') == 'acquire 50 %, track 25 %, inner 25 %'


def test_a_level_is_ok_warn_or_error():
    with pytest.raises(ValueError, match='OK, WARN or ERROR'):
        Health(3, 'stale')


def test_the_settle_watch_reports_settle_times_and_warns_once_per_unsettled_decision():
    from dlmpc_ros.health import SettleWatch
    watch = SettleWatch()
    for settled, time in ((True, 13), (True, None), (True, 15), (True, 14)):
        watch.add(settled, time)
    quiet = Findings()
    watch.report(quiet, timeout=100, tolerance=0.005)
    assert not quiet.warnings
    assert quiet.values['settle_round_trips_median'] == 14.0
    assert quiet.values['settle_round_trips_max'] == 15
    watch.add(False, None)
    late = Findings()
    watch.report(late, timeout=100, tolerance=0.005)
    assert late.values['decisions_unsettled'] == 1
    assert 'settle_timeout = 100' in late.warnings[0] and '14 round trips' in late.warnings[0]
    again = Findings()
    watch.report(again, timeout=100, tolerance=0.005)  # nothing new since the last report
    assert not again.warnings
