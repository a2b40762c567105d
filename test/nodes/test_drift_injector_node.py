"""drift_injector in its own process, driven by state messages from the test (as a laser
or a hardware driver would publish them)."""

import math

import pytest

from dlmpc_ros import interfaces as itf
from dlmpc_ros.core.drift import make_scenario
from test.nodes.rosutil import NodeProcess, Probe

MODULE = 'dlmpc_ros.nodes.drift_injector_node'


def _state(round_trip):
    return [round_trip, 4.0, 30.0, 4.0 / 30.0, 16.0, 3.0, 0.0, 0.0, 0.0, 0.0]


def test_publishes_k_of_the_next_round_trip(ros_env, tmp_path):
    probe = Probe()
    node = NodeProcess(MODULE, ros_env, tmp_path / 'drift.log', '-p', 'scenario:=steps',
                       '-p', 'times:=[3.0,6.0]', '-p', 'values:=[0.1,-0.2]')
    try:
        ks = probe.listen(itf.TOPIC_BIREFRINGENCE)
        probe.wait_matched(itf.TOPIC_STATE)
        probe.spin_until(lambda: probe.node.count_publishers(itf.TOPIC_BIREFRINGENCE) > 0
                         and probe.node.count_subscribers(itf.TOPIC_STATE) > 0, 30, 'the graph')
        # Malformed state messages are dropped, not answered.
        for bad in ([], [1.0, 2.0], [math.nan, *_state(1)[1:]], [-4.0, *_state(1)[1:]],
                    [2.5, *_state(1)[1:]]):
            probe.publish(itf.TOPIC_STATE, bad)
        for r in range(0, 8):
            probe.publish(itf.TOPIC_STATE, _state(r), itf.STATE_FIELDS)
        probe.spin_until(lambda: len(ks) >= 8, 30, '8 K messages')
        scenario = make_scenario('steps', times=[3.0, 6.0], values=[0.1, -0.2])
        assert [m.data[0] for m in ks] == pytest.approx([scenario(r + 1) for r in range(8)])
        assert ks[0].layout.dim[0].label == 'K'
    finally:
        code = node.stop()
        probe.close()
    assert code == 0, node.output()
    assert 'dropped a message on /laser/state' in node.output()


def test_bad_scenario_settings_stop_the_node_with_one_clear_message(ros_env, tmp_path):
    node = NodeProcess(MODULE, ros_env, tmp_path / 'drift.log', '-p', 'scenario:=sinusoidal',
                       '-p', 'amplitude:=0.5')
    assert node.proc.wait(60) == 2
    assert 'outside the model range' in node.output()
    assert 'Traceback' not in node.output()


def test_a_round_trip_far_ahead_is_dropped_and_the_walk_goes_on(ros_env, tmp_path):
    """One /laser/state with round trip 1e9 (a count below 2^53) once made a random walk
    generate its whole path: 100 % CPU, 1.4 GB in a minute, no K, SIGINT ignored."""
    probe = Probe()
    node = NodeProcess(MODULE, ros_env, tmp_path / 'drift.log', '-p', 'scenario:=random_walk',
                       '-p', 'seed:=3')
    try:
        ks = probe.listen(itf.TOPIC_BIREFRINGENCE)
        probe.wait_matched(itf.TOPIC_STATE)
        probe.spin_until(lambda: probe.node.count_publishers(itf.TOPIC_BIREFRINGENCE) > 0,
                         30, 'the drift publisher')
        probe.publish(itf.TOPIC_STATE, _state(1e9), itf.STATE_FIELDS)
        for r in range(1, 6):
            probe.publish(itf.TOPIC_STATE, _state(r), itf.STATE_FIELDS)
        probe.spin_until(lambda: len(ks) >= 5, 10, 'K for the next states')
        walk = make_scenario('random_walk', seed=3)
        assert [m.data[0] for m in ks] == pytest.approx([walk(r + 1) for r in range(1, 6)])
    finally:
        code = node.stop()
        probe.close()
    assert code == 0, node.output()
    assert 'runs more than 1000000 past the furthest seen' in node.output()
