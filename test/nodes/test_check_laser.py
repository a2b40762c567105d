"""dlmpc-check-laser against laser_sim and against deliberately broken lasers.

The broken lasers are this module run as a script: ``python -m test.nodes.test_check_laser
MODE`` starts a 200 Hz fake laser with one fault (see :class:`FakeLaserNode`).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import conformance as cf
from dlmpc_ros import interfaces as itf
from dlmpc_ros.ros.io import QOS, vector_message
from test.nodes.rosutil import NodeProcess

ROOT = Path(__file__).resolve().parents[2]
CHECK = [sys.executable, '-m', 'dlmpc_ros.cli.check_laser', '--timeout', '30']


class FakeLaserNode(Node):
    """A laser with one fault: ``nan`` publishes M = NaN every 25th round trip; ``deaf``
    never applies a command and publishes no status; ``clamps`` clamps out-of-range angles
    to [-pi, pi] instead of dropping the message; ``slow`` has servos that start 6 round
    trips after a command and turn 0.04 rad per round trip (a full step of 0.25 rad takes
    13 round trips)."""

    def __init__(self, mode: str) -> None:
        super().__init__('fake_laser')
        self.mode = mode
        self.angles = [-0.39, -0.25, 0.52, -0.14]
        self.target, self.lag = list(self.angles), 0
        self.round_trip = 0
        self.counts = dict.fromkeys(itf.LASER_STATUS_FIELDS[2:], 0)
        self.pubs = {topic: self.create_publisher(Float64MultiArray, topic, QOS[topic])
                     for topic in (itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE,
                                   itf.TOPIC_LASER_STATUS)}
        self.create_subscription(Float64MultiArray, itf.TOPIC_ANGLES_CMD, self._on_angles,
                                 QOS[itf.TOPIC_ANGLES_CMD])
        self.create_timer(1 / 200, self._round_trip)
        if mode != 'deaf':
            self.create_timer(1.0, self._status)

    def _on_angles(self, msg: Float64MultiArray) -> None:
        data = list(msg.data)
        if self.mode == 'deaf':
            return
        if len(data) != 4 or not all(map(math.isfinite, data)) or (
                self.mode != 'clamps' and max(map(abs, data)) > 2 * math.pi):
            self.counts['messages_rejected'] += 1
            return
        self.target = [min(max(a, -math.pi), math.pi) for a in data]
        self.lag = 6 if self.mode == 'slow' else 0
        if self.mode != 'slow':
            self.angles = list(self.target)
        self.counts['commands_received'] += 1

    def _round_trip(self) -> None:
        self.round_trip += 1
        if self.lag > 0:
            self.lag -= 1
        else:
            self.angles = [a + min(max(t - a, -0.04), 0.04)
                           for a, t in zip(self.angles, self.target)]
        e, m = 4.0, 30.0
        if self.mode == 'nan' and self.round_trip % 25 == 0:
            m = math.nan
        self.pubs[itf.TOPIC_STATE].publish(vector_message(
            itf.STATE_FIELDS, [self.round_trip, e, m, e / m, e * e, 1.0, *self.angles]))
        self.pubs[itf.TOPIC_OBJECTIVE].publish(vector_message(itf.OBJECTIVE_FIELDS, [e / m]))

    def _status(self) -> None:
        self.pubs[itf.TOPIC_LASER_STATUS].publish(vector_message(
            itf.LASER_STATUS_FIELDS, [self.round_trip, 200.0, *self.counts.values()]))


def _check(ros_env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CHECK, *args], env=ros_env, capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def _line(output: str, key: str) -> str:
    return next(line for line in output.splitlines() if line.startswith(f'({key})'))


def test_laser_sim_passes_every_check(ros_env, tmp_path):
    laser = NodeProcess('dlmpc_ros.nodes.laser_sim_node', ros_env, tmp_path / 'laser.log',
                        '-p', 'round_trips_per_second:=500.0')
    try:
        # On a loaded machine a command can reach the 500 Hz simulator tens of ms late (its
        # round trips run on meanwhile), so the bound here is looser than the default 10.
        proc = _check(ros_env, '--duration', '3', '--max-round-trips', '100',
                      '--json', str(tmp_path / 'report.json'))
    finally:
        code = laser.stop()
    out = proc.stdout
    assert proc.returncode == 0, out + proc.stderr + laser.output()[-3000:]
    for key in 'abcdef':
        assert ' PASS ' in _line(out, key), out
    assert out.rstrip().endswith('result: PASS')
    report = json.loads((tmp_path / 'report.json').read_text())
    assert report['passed'] and [c['status'] for c in report['checks']] == ['PASS'] * 6
    stream = report['checks'][0]['figures']
    assert stream['rate_hz'] == pytest.approx(500, rel=0.1)
    commands = report['checks'][2]['figures']
    assert commands['reached'] == 5 and commands['settle_round_trips_max'] <= 100
    assert code == 0
    log = laser.output()
    assert 'dropped a message on /laser/angles_cmd' in log and 'Traceback' not in log


@pytest.mark.parametrize('mode, failing, why, extra', [
    ('nan', ['(a) state stream'], 'M is nan', []),
    ('deaf', ['(c) angle commands', '(d) malformed commands', '(e) status'], 'not reached',
     []),
    ('clamps', ['(d) malformed commands'], 'it applied the', []),
    ('slow', ['(c) angle commands'], 'set their settle_timeout above 1',
     ['--max-round-trips', '10']),
])
def test_a_broken_laser_fails_the_check_it_breaks(ros_env, tmp_path, mode, failing, why,
                                                  extra):
    log = tmp_path / 'fake.log'
    with open(log, 'wb') as handle:
        fake = subprocess.Popen([sys.executable, '-m', 'test.nodes.test_check_laser', mode],
                                env=ros_env, cwd=ROOT, stdout=handle, stderr=subprocess.STDOUT)
        try:
            proc = _check(ros_env, '--duration', '2', *extra)
        finally:
            fake.terminate()
            fake.wait(30)
    out = proc.stdout
    assert proc.returncode == 1, out + proc.stderr + log.read_text()
    result = out.strip().splitlines()[-1]
    assert result.startswith('result: FAIL') and all(name in result for name in failing), out
    assert why in out, out
    if mode == 'slow':  # the settle time of a full step (lag 6, 7 round trips of turning)
        assert 'a full step (0.25 rad) settles in 1' in out, out


def test_no_laser_and_bad_arguments_exit_2(ros_env):
    proc = _check(ros_env, '--timeout', '2')
    assert proc.returncode == 2 and 'no node publishes /laser/state' in proc.stderr
    proc = _check(ros_env, '--tolerance', 'nan')
    assert proc.returncode == 2 and '--tolerance' in proc.stderr


def _states(rows: list[list[float]], dt: float = 0.01) -> list[cf.Sample]:
    label = ','.join(itf.STATE_FIELDS)
    return [cf.Sample(i * dt, i * dt, tuple(map(float, r)), label) for i, r in enumerate(rows)]


def _row(rt: float, angles=(0.1, 0.2, 0.3, 0.4), e: float = 4.0, m: float = 30.0):
    return [rt, e, m, e / m, e * e, 1.0, *angles]


def test_state_stream_flags_round_trips_that_do_not_increase_and_stalls():
    settings = cf.Settings(period=10)
    steady = _states([_row(r) for r in range(1, 101)])
    assert cf.check_state_stream(steady, 0.0, 1.0, settings).status == cf.PASS
    sevens = _states([_row(r) for r in range(7, 707, 7)])  # every 7th round trip published:
    result = cf.check_state_stream(sevens, 0.0, 1.0, settings)  # decisions need no multiple
    assert result.status == cf.PASS and 'round_trip steps 7..7' in result.summary
    repeated = _states([_row(r // 2) for r in range(2, 202)])
    result = cf.check_state_stream(repeated, 0.0, 1.0, settings)
    assert any('did not increase' in p for p in result.problems)
    stalled = _states([_row(r) for r in range(1, 51)])  # stops half way through the window
    result = cf.check_state_stream(stalled, 0.0, 1.0, settings)
    assert any('no /laser/state for' in p for p in result.problems)


def test_objective_and_malformed_commands_are_judged_by_value():
    settings = cf.Settings()
    rows = [_row(r, e=4.0 + 0.01 * r) for r in range(1, 51)]
    states = _states(rows)
    objectives = [cf.Sample(x.received, x.sent, (x.data[3],), 'O') for x in states]
    assert cf.check_objective(states, objectives, settings).status == cf.PASS
    rows[10][3] *= 1.01
    result = cf.check_objective(_states(rows), objectives, settings)
    assert result.status == cf.FAIL and 'O != E/M' in result.problems[0]

    before = (0.1, 0.2, 0.3, 0.4)
    sent = cf.malformed_commands(before, settings.step, settings.angle_limit)
    assert [len(d) for _, d in sent] == [0, 3, 5, 4, 4, 4, 4, 4, 4]
    assert all(itf.vector_fault(d, itf.ANGLE_FIELDS, settings.angle_limit) for _, d in sent)
    bad = next(d for name, d in sent if name == 'above the range')
    applied = [a if abs(a) <= math.pi else math.pi for a in bad]  # a laser that clamps
    after = _states([_row(r, before) for r in range(1, 5)] + [_row(5, applied)])
    result = cf.check_malformed(sent, before, after, 0.0, 0.05, None, settings)
    assert result.status == cf.FAIL
    assert any('it applied the above the range command' in p for p in result.problems)


if __name__ == '__main__':  # the fake laser: python -m test.nodes.test_check_laser MODE
    from dlmpc_ros.ros.params import run_node

    sys.exit(run_node(lambda: FakeLaserNode(sys.argv[1])))


def test_the_diagnostics_check_is_optional_and_fails_only_on_an_error():
    lasers = ['/my_driver']
    absent = cf.check_diagnostics([(1.0, 'other_node', 0, 'fine')], lasers, 0.0, 5.0)
    assert absent.status == cf.WARN and 'my_driver' in absent.notes[0]
    fine = cf.check_diagnostics([(t, 'my_driver', 1 if t == 2 else 0, 'ok')
                                 for t in (1.0, 2.0, 3.0)], lasers, 0.0, 4.0)
    assert fine.status == cf.PASS and '2 OK, 1 WARN' in fine.summary
    broken = cf.check_diagnostics([(1.0, 'my_driver', 2, 'laser lost')], lasers, 0.0, 2.0)
    assert broken.status == cf.FAIL and 'laser lost' in broken.problems[0]
