"""The estimator and controller nodes as real processes, probed over ROS; the controller
nodes' decision loop on the probe's own publishers."""

import math
import time
from pathlib import Path

import numpy as np
import pytest
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.control.step import MODES, AngleLimits, ControlStep, PeriodMeasurement
from dlmpc_ros.learning.checkpoint import load_checkpoint
from test.nodes.rosutil import NodeProcess, Probe

ESTIMATOR = 'dlmpc_ros.nodes.vae_estimator_node'
MPC = 'dlmpc_ros.nodes.mpc_controller_node'
BASELINE = 'dlmpc_ros.nodes.baseline_controller_node'
LASER = 'dlmpc_ros.nodes.laser_sim_node'
ROOT = Path(__file__).resolve().parents[2]
ANGLES = [-0.39, -0.25, 0.52, -0.14]


@pytest.fixture
def probe(ros_env):
    p = Probe()
    yield p
    p.close()


def _state(round_trip, e=3.2, m=18.0, angles=ANGLES):
    return [round_trip, e, m, e / m, e, 1.0, *angles]


def _periods(probe, status, ends, period=10, estimate=True, commands=(), **state):
    """Publish each control period's states (its estimate first) and wait for its decision,
    so that every decision sees its own estimate however slow the machine is. The states
    report the latest of ``commands`` as their angles (a laser whose servos are instant)."""
    for end in ends:
        if estimate:
            probe.publish(itf.TOPIC_ESTIMATE, [end, 0.2, 0.5, 0.2, 0.1])
        angles = list(commands[-1].data) if commands else ANGLES
        for r in range(end - period + 1, end + 1):
            probe.publish(itf.TOPIC_STATE, _state(r, angles=angles, **state),
                          itf.STATE_FIELDS)
        due = len(status) + 1
        probe.spin_until(lambda due=due: len(status) >= due and (
            not isinstance(commands, list) or len(commands) >= due), 60,
            f'the decision at round trip {end}')


def _start(module, ros_env, tmp_path, *params):
    args = []
    for p in params:
        args += ['-p', p]
    return NodeProcess(module, ros_env, tmp_path / f'{module.rsplit(".", 1)[1]}.log', *args)


def _start_mpc(probe, ros_env, tmp_path, *params, estimates=True) -> NodeProcess:
    """The DL-MPC controller node, once it reads the probe's states and (``estimates``: the
    paper's loops read them) estimates; the probe reads its measurements, as the estimator
    would."""
    probe.listen(itf.TOPIC_MEASUREMENT)
    node = _start(MPC, ros_env, tmp_path, 'period:=10', *params)
    try:
        probe.wait_matched(itf.TOPIC_STATE)
        if estimates:
            probe.wait_matched(itf.TOPIC_ESTIMATE)
    except BaseException:
        node.stop()
        raise
    return node


def _measurement(round_trip, e=3.2, m=18.0, angles=ANGLES):
    return [round_trip, e, m, *angles, 1.0, -1.0]


def test_estimator_estimates_each_measurement_and_drops_bad_ones(ros_env, tmp_path, probe):
    from dlmpc_ros.control.factory import load_estimator
    from dlmpc_ros.paths import models_dir
    estimates = probe.listen(itf.TOPIC_ESTIMATE)
    node = _start(ESTIMATOR, ros_env, tmp_path)
    try:
        probe.wait_matched(itf.TOPIC_MEASUREMENT)
        for bad in ([], [1.0, 2.0], [5, math.nan, *_measurement(0)[2:]],
                    [5.5, *_measurement(0)[1:]], [-5, *_measurement(0)[1:]]):
            probe.publish(itf.TOPIC_MEASUREMENT, bad)
        energies = (2.0, 2.5, 3.0, 3.5, 4.0, 2.0)
        for r, e in zip((10, 23, 30, 47, 57, 67), energies):  # decisions come when due
            probe.publish(itf.TOPIC_MEASUREMENT, _measurement(r, e=e), itf.MEASUREMENT_FIELDS)
        probe.spin_until(lambda: len(estimates) >= 6, 60, '6 estimates')
        rows = [list(m.data) for m in estimates]
        assert [row[0] for row in rows] == [10, 23, 30, 47, 57, 67]
        assert all(map(math.isfinite, sum(rows, [])))
        assert estimates[0].layout.dim[0].label.startswith('round_trip,surrogate,latency_ms,z1')
        assert node.proc.poll() is None
    finally:
        assert node.stop() == 0
    assert 'dropped a message on /controller/measurement' in node.output()
    expected = load_estimator(models_dir())
    for row, e in zip(rows, energies):
        surrogate, _ = expected.update(np.array([e, 18.0, *ANGLES]))
        assert row[1] == pytest.approx(surrogate, rel=1e-5)


def test_a_decision_waits_until_the_reported_angles_reach_the_command(
        ros_env, tmp_path, probe):
    commands = probe.listen(itf.TOPIC_ANGLES_CMD)
    measurements = probe.listen(itf.TOPIC_MEASUREMENT)
    node = _start(BASELINE, ros_env, tmp_path, 'controller:=fixed_best', 'period:=10',
                  'measurement_round_trips:=3', 'settle_timeout:=1000')
    try:
        probe.wait_matched(itf.TOPIC_STATE)
        for r in range(1, 11):
            probe.publish(itf.TOPIC_STATE, _state(r), itf.STATE_FIELDS)
        probe.spin_until(lambda: len(commands) >= 1, 30, 'the first command')
        target = list(commands[0].data)
        assert np.abs(np.array(target) - ANGLES).max() > 0.01  # the servos must move
        # the servos start late: at the old angles until round trip 24, then at the command
        # within the encoder's noise; the decision is due once 3 round trips are at it
        for r in range(11, 30):
            angles = ANGLES if r < 25 else [a + 0.001 * (-1) ** r for a in target]
            probe.publish(itf.TOPIC_STATE, _state(r, e=float(r), angles=angles),
                          itf.STATE_FIELDS)
        probe.spin_until(lambda: len(measurements) >= 2, 30, 'the second decision')
        second = list(measurements[1].data)
        assert second[0] == 27 and second[1] == pytest.approx(26.0)  # round trips 25-27
        assert second[3:7] == pytest.approx(target, abs=0.0011)
        assert second[7:] == [1.0, 15.0]  # settled, 15 round trips after the decision
    finally:
        assert node.stop() == 0


def _subscriptions_once_seen(probe, expected: set[str]) -> set[str]:
    """The topics mpc_controller subscribes, once discovery has shown at least ``expected``:
    each reader is discovered on its own, after the node's name (read at once, one was
    missing in a CI run)."""
    def seen() -> set[str]:
        return {name for name, _ in probe.node.get_subscriber_names_and_types_by_node(
            'mpc_controller', '/')}
    probe.spin_until(lambda: seen() >= expected, 30, f'its subscriptions {sorted(expected)}')
    return seen()


def test_mpc_controller_acts_each_period_holds_without_estimator_and_never_reads_true_k(
        ros_env, tmp_path, probe):
    commands = probe.listen(itf.TOPIC_ANGLES_CMD)
    status = probe.listen(itf.TOPIC_CONTROLLER_STATUS)
    node = _start_mpc(probe, ros_env, tmp_path, 'estimator_timeout:=1.0', 'max_step:=0.1',
                      'track:=false')  # the inner loop and hold; tracking below
    try:
        probe.spin_until(lambda: 'mpc_controller' in probe.node.get_node_names(), 30, 'node')
        expected = {itf.TOPIC_STATE, itf.TOPIC_ESTIMATE}
        assert _subscriptions_once_seen(probe, expected) == expected
        # With estimates: the inner loop maps the surrogate to angles, one step at a time.
        _periods(probe, status, [10, 20, 30], commands=commands)
        rows = [list(m.data) for m in status]
        assert [row[0] for row in rows] == [10, 20, 30]
        assert [MODES[int(row[1])] for row in rows] == ['inner'] * 3
        assert all(row[6] == 1.0 and row[5] == pytest.approx(0.2) for row in rows)
        for before, m in zip([ANGLES, *(c.data for c in commands)], commands):
            assert np.abs(np.array(m.data) - before).max() <= 0.1 + 1e-9
        # A silent estimator: the controller acts after the timeout, holds, and says so.
        held = list(commands[-1].data)
        for r in range(31, 41):
            probe.publish(itf.TOPIC_STATE, _state(r, angles=held), itf.STATE_FIELDS)
        probe.spin_until(lambda: len(status) >= 4, 30, 'a decision without estimate')
        row = list(status[3].data)
        assert MODES[int(row[1])] == 'hold' and row[6] == 0.0 and row[7] == 1.0
        assert list(commands[-1].data) == pytest.approx(held)
        assert all(map(math.isfinite, sum((list(m.data) for m in status), [])))
    finally:
        assert node.stop() == 0
    for kind in ('kmap', 'mprnn'):  # nothing the controller loads holds K
        payload = load_checkpoint(ROOT / 'models' / f'{kind}.pt', kind)
        names = ' '.join([*payload['state_dict'], *payload['config']]).lower()
        assert 'birefringence' not in names and 'truth' not in names
    with np.load(ROOT / 'models' / 'track_curve.npz', allow_pickle=False) as curve:
        # a curve of angles over an estimate axis, with its steady O: no run's K
        assert set(curve.files) == {'grid', 'angles', 'objective', 'schema_version'}


def test_mpc_controller_tracks_the_curve_once_locked_and_reads_no_estimate(
        ros_env, tmp_path, probe):
    from dlmpc_ros.control.dlmpc_config import TrackingConfig
    from dlmpc_ros.learning.curve import load_curve
    status = probe.listen(itf.TOPIC_CONTROLLER_STATUS)
    commands = probe.listen(itf.TOPIC_ANGLES_CMD)
    # the default strategy: acquisition, tracking and hold read no surrogate, so the node
    # neither subscribes the estimate nor waits for it (a long timeout would show)
    node = _start_mpc(probe, ros_env, tmp_path, 'estimator_timeout:=30.0', 'max_step:=3.0',
                      estimates=False)
    try:
        probe.spin_until(lambda: 'mpc_controller' in probe.node.get_node_names(), 30, 'node')
        assert _subscriptions_once_seen(probe, {itf.TOPIC_STATE}) == {itf.TOPIC_STATE}
        # A locked laser (O = 3.2 / 18 is above the lock level): held, then tracking.
        patience = TrackingConfig().entry_patience
        _periods(probe, status, range(10, 10 * patience + 31, 10), estimate=False,
                 commands=commands)
    finally:
        assert node.stop() == 0
    rows = [list(m.data) for m in status]
    modes = [MODES[int(row[1])] for row in rows]
    assert modes[:patience - 1] == ['hold'] * (patience - 1)
    assert modes[patience - 1:] == ['track'] * (len(rows) - patience + 1)
    grid, angles, _ = load_curve(ROOT / 'models' / 'track_curve.npz')
    for row, cmd in zip(rows[patience - 1:], commands[patience - 1:]):
        assert row[6] == 1.0 and grid[0] <= row[5] <= grid[-1]  # the curve estimate, K units
        gap = (np.array(cmd.data) - np.array([np.interp(row[5], grid, a) for a in angles.T])
               + np.pi / 2) % np.pi - np.pi / 2
        assert np.abs(gap).max() < 0.2  # on the curve, within the dither
    assert all(row[7] == -1.0 for row in rows)  # no estimate: none expected
    assert 'no estimate' not in node.output()


def test_lockstep_laser_waits_for_each_command(ros_env, tmp_path, probe):
    states = probe.listen(itf.TOPIC_STATE)
    probe.publisher(itf.TOPIC_ANGLES_CMD)
    node = _start(LASER, ros_env, tmp_path, 'wait_for_subscribers:=1', 'lockstep_period:=10',
                  'lockstep_timeout:=30.0')
    try:
        probe.wait_matched(itf.TOPIC_ANGLES_CMD)
        probe.spin_until(lambda: len(states) >= 10, 60, '10 states')
        for _ in range(20):
            probe.executor.spin_once(timeout_sec=0.05)
        assert len(states) == 10, 'the laser went on without a command'
        probe.publish(itf.TOPIC_ANGLES_CMD, [0.1, 0.2, 0.3, 0.4], itf.ANGLE_FIELDS)
        probe.spin_until(lambda: len(states) >= 20, 30, '10 more states')
        for _ in range(20):
            probe.executor.spin_once(timeout_sec=0.05)
        assert len(states) == 20
        assert list(states[10].data)[6:] == pytest.approx([0.1, 0.2, 0.3, 0.4])
    finally:
        assert node.stop() == 0


@pytest.mark.parametrize('acquire', [True, False])
def test_mpc_controller_scans_for_lock_while_the_laser_is_off_its_pulse(
        ros_env, tmp_path, probe, acquire):
    status = probe.listen(itf.TOPIC_CONTROLLER_STATUS)
    commands = probe.listen(itf.TOPIC_ANGLES_CMD)
    node = _start_mpc(probe, ros_env, tmp_path, 'acquire_patience:=2',
                      f'acquire:={str(acquire).lower()}', estimates=False)
    try:
        _periods(probe, status, [10, 20, 30, 40, 50], e=0.3, m=30.0,  # O = 0.01: no pulse
                 commands=commands, estimate=False)
        modes = [MODES[int(m.data[1])] for m in status]
        # with a curve no inner loop: the angles hold until the scan starts (or for good)
        assert modes == (['hold'] * 2 + ['acquire'] * 3 if acquire else ['hold'] * 5)
    finally:
        assert node.stop() == 0


def _only_answer(probe, status, n) -> list[float]:
    """The n-th decision, after checking for half a second that no other follows it."""
    probe.spin_until(lambda: len(status) >= n, 20, f'decision {n}')
    for _ in range(10):
        probe.executor.spin_once(timeout_sec=0.05)
    assert len(status) == n, f'{len(status)} decisions where {n} were due'
    return list(status[n - 1].data)


def test_controller_answers_every_period_even_when_the_next_state_beats_the_estimate(
        ros_env, tmp_path, probe):
    status = probe.listen(itf.TOPIC_CONTROLLER_STATUS)
    node = _start_mpc(probe, ros_env, tmp_path, 'estimator_timeout:=30.0', 'track:=false')
    try:
        for r in [*range(1, 11), 10, *range(11, 21), 20]:  # two periods (each state 10 and
            probe.publish(itf.TOPIC_STATE, _state(r), itf.STATE_FIELDS)  # 20 twice), no estimate
        first = _only_answer(probe, status, 1)
        assert first[0] == 10 and MODES[int(first[1])] == 'hold' and first[6] == 0.0
        probe.publish(itf.TOPIC_ESTIMATE, [20, 0.2, 0.5, 0.2, 0.1])
        second = _only_answer(probe, status, 2)  # and not a second answer to the repeat
        assert second[0] == 20 and MODES[int(second[1])] == 'inner' and second[6] == 1.0
    finally:
        assert node.stop() == 0
    assert "no estimate for round trip 10 before the next period's state" in node.output()


class _NotFiniteFirst:
    """A controller whose first ``bad`` commands are not finite; then it holds the angles."""

    name = 'not_finite_first'

    def __init__(self, bad: int) -> None:
        self.bad, self.steps = bad, 0

    def step(self, measurement, surrogate=None) -> ControlStep:
        self.steps += 1
        angles = np.full(4, np.nan) if self.steps <= self.bad else np.asarray(measurement[2:6])
        return ControlStep(angles=angles, mode='hold')


def test_the_decision_loop_never_sends_a_non_finite_command_and_starts_the_controller_afresh(
        probe):
    from dlmpc_ros.ros.controller_base import Publishers
    from dlmpc_ros.ros.decision_loop import DecisionLoop
    commands = probe.listen(itf.TOPIC_ANGLES_CMD)
    measurements = probe.listen(itf.TOPIC_MEASUREMENT)
    warnings, replaced = [], []
    first, second = _NotFiniteFirst(bad=1), _NotFiniteFirst(bad=0)
    topics = (itf.TOPIC_ANGLES_CMD, itf.TOPIC_CONTROLLER_STATUS, itf.TOPIC_MEASUREMENT)
    loop = DecisionLoop(first, AngleLimits(), PeriodMeasurement(period=2, round_trips=1),
                        Publishers(*(probe.publisher(t) for t in topics)),
                        itf.RateLimitedLog(warnings.append), now=time.monotonic,
                        fresh=lambda old: replaced.append(old) or second)
    for r in range(1, 5):  # decisions at round trips 2 and 4, the laser at ANGLES
        loop.on_state(Float64MultiArray(data=_state(r)))
    probe.spin_until(lambda: len(commands) >= 2 and len(measurements) >= 2, 30,
                     'two commands')
    for cmd in commands:  # the angles held, never NaN
        np.testing.assert_allclose(cmd.data, ANGLES)
    assert replaced == [first] and loop.controller is second and second.steps == 1
    assert 'controller produced' in warnings[0] and loop.steps == 2
