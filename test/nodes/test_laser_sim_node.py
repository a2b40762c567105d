"""laser_sim as a real node in its own process, probed from the test over ROS."""

import math

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters

from dlmpc_ros import interfaces as itf
from test.nodes.rosutil import NodeProcess, Probe

MODULE = 'dlmpc_ros.nodes.laser_sim_node'


@pytest.fixture
def probe(ros_env):
    p = Probe()
    yield p
    p.close()


def _start(ros_env, tmp_path, *params):
    args = []
    for p in params:
        args += ['-p', p]
    return NodeProcess(MODULE, ros_env, tmp_path / 'laser_sim.log', *args)


def test_publishes_every_round_trip_and_applies_commands(ros_env, tmp_path, probe):
    states = probe.listen(itf.TOPIC_STATE)
    objectives = probe.listen(itf.TOPIC_OBJECTIVE)
    truths = probe.listen(itf.TOPIC_SIM_TRUTH)
    node = _start(ros_env, tmp_path, 'wait_for_subscribers:=1', 'max_round_trips:=100000')
    try:
        probe.spin_until(lambda: len(states) >= 300, 120, '300 state messages')
        rows = [list(m.data) for m in states]
        assert [r[0] for r in rows] == list(range(1, len(rows) + 1)), 'a round trip was missed'
        assert all(len(r) == len(itf.STATE_FIELDS) and all(map(math.isfinite, r)) for r in rows)
        assert states[0].layout.dim[0].label == ','.join(itf.STATE_FIELDS)
        assert rows[0][6:] == pytest.approx([-0.39, -0.25, 0.52, -0.14])
        assert all(r[3] == pytest.approx(r[1] / r[2]) for r in rows)
        probe.spin_until(lambda: len(objectives) >= 10, 30, 'objective messages')
        assert objectives[0].layout.dim[0].label == 'O'

        # Malformed commands are dropped with a warning; the node keeps running.
        probe.wait_matched(itf.TOPIC_ANGLES_CMD)
        probe.wait_matched(itf.TOPIC_BIREFRINGENCE)
        for bad in ([], [0.1, 0.2], [math.nan, 0, 0, 0], [0, math.inf, 0, 0], [0, 0, 1e308, 0]):
            probe.publish(itf.TOPIC_ANGLES_CMD, bad)
        for bad in ([], [math.nan], [-math.inf], [0.1, 0.2], [5.0]):
            probe.publish(itf.TOPIC_BIREFRINGENCE, bad)
        count = len(states)
        probe.spin_until(lambda: len(states) > count + 200, 60, 'more state messages')
        assert all(list(m.data)[6:] == pytest.approx([-0.39, -0.25, 0.52, -0.14])
                   for m in states[count:])

        # Good commands take effect within a few round trips.
        new = [0.3, -1.1, 0.7, 0.25]
        probe.publish(itf.TOPIC_ANGLES_CMD, new, itf.ANGLE_FIELDS)
        probe.spin_until(lambda: list(states[-1].data)[6:] == pytest.approx(new), 30,
                         'the new angles in the state')
        probe.publish(itf.TOPIC_BIREFRINGENCE, [-0.25], itf.BIREFRINGENCE_FIELDS)
        probe.spin_until(lambda: truths and truths[-1].data[1] == -0.25, 30, 'the new K')
        rts = [int(m.data[0]) for m in truths]
        assert rts == list(range(rts[0], rts[0] + len(rts)))
        assert {m.data[1] for m in truths} == {0.1, -0.25}
        assert all(math.isfinite(x) for m in states for x in m.data)
    finally:
        code = node.stop()
    log = node.output()
    assert code == 0, log
    assert 'dropped a message on /laser/angles_cmd' in log
    assert 'dropped a message on /laser/birefringence' in log
    assert 'Traceback' not in log


def test_parameters_are_validated_at_runtime(ros_env, tmp_path, probe):
    node = _start(ros_env, tmp_path, 'round_trips_per_second:=200.0')
    client = probe.node.create_client(SetParameters, '/laser_sim/set_parameters')
    try:
        probe.spin_until(client.service_is_ready, 60, 'the parameter service')

        def set_param(name, kind, **value):
            request = SetParameters.Request(parameters=[ParameterMsg(
                name=name, value=ParameterValue(type=kind, **value))])
            return probe.call(client, request, 10).results[0]

        bad = set_param('pump', ParameterType.PARAMETER_DOUBLE, double_value=-1.0)
        assert not bad.successful and 'pump out of range' in bad.reason  # its descriptor
        bad = set_param('cross_phase', ParameterType.PARAMETER_DOUBLE, double_value=0.5)
        assert not bad.successful and 'cross_phase + four_wave' in bad.reason
        readonly = set_param('points', ParameterType.PARAMETER_INTEGER, integer_value=512)
        assert not readonly.successful
        good = set_param('pump', ParameterType.PARAMETER_DOUBLE, double_value=1.8)
        assert good.successful
    finally:
        assert node.stop() == 0, node.output()


@pytest.mark.parametrize('setting, message', [
    ('points:=8', 'points = 8 is outside its range [16, 4096]'),  # its descriptor's range
    ('initial:=gauss', 'initial must be'),  # the node's own check
])
def test_invalid_start_parameters_stop_the_node_with_one_clear_message(ros_env, tmp_path,
                                                                      setting, message):
    node = _start(ros_env, tmp_path, setting)
    assert node.proc.wait(60) == 2
    log = node.output()
    assert 'cannot start' in log and message in log
    assert 'Traceback' not in log
