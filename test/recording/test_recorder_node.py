"""The recorder and laser_sim as real node processes: every round trip lands in the bag."""

from __future__ import annotations

import signal
import subprocess
import time

import numpy as np
import pytest

from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording import BagError, check_round_trips, read_bag, read_metadata, repair
from test.nodes.rosutil import NodeProcess
from test.recording.bagutil import flushed_counts

RECORDER = 'dlmpc_ros.nodes.recorder_node'
LASER_SIM = 'dlmpc_ros.nodes.laser_sim_node'
STREAMS = (itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE, itf.TOPIC_SIM_TRUTH)


def _wait(condition, timeout: float, what: str, *processes: NodeProcess) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        for node in processes:
            if node.proc.poll() is not None:
                raise AssertionError(f'{node.log.name} exited with {node.proc.returncode} '
                                     f'while waiting for {what}:\n{node.output()}')
        if time.monotonic() > deadline:
            raise TimeoutError(f'timed out after {timeout} s waiting for {what}')
        time.sleep(0.1)


def _laser_sim(ros_env, tmp_path, round_trips: int) -> NodeProcess:
    return NodeProcess(LASER_SIM, ros_env, tmp_path / 'laser_sim.log', '-p',
                       f'max_round_trips:={round_trips}', '-p', 'wait_for_subscribers:=1')


def test_bag_holds_every_round_trip_of_a_run_once_and_in_order(ros_env, tmp_path):
    bag = tmp_path / 'run'
    recorder = NodeProcess(RECORDER, ros_env, tmp_path / 'recorder.log', '-p', f'output:={bag}')
    laser = _laser_sim(ros_env, tmp_path, 3000)
    try:
        assert laser.proc.wait(120) == 0, laser.output()
        # The recorder writes its open chunk every flush_period: wait until all is on disk
        # (or give up and let the checks below show what is missing).
        try:
            _wait(lambda: all(flushed_counts(bag)[t] >= 3000 for t in STREAMS), 30,
                  'all 3 x 3000 messages in the bag', recorder)
        except TimeoutError:
            pass
    finally:
        laser.stop()
        code = recorder.stop()
    log = recorder.output()
    assert code == 0, log
    assert 'Traceback' not in log
    topics = read_bag(bag)
    gaps = {t: check_round_trips(topics[t].data[:, 0]).gaps for t in STREAMS[::2]}
    assert [len(topics[t]) for t in STREAMS] == [3000] * 3, gaps
    assert topics[itf.TOPIC_STATE].fields == itf.STATE_FIELDS
    expected = np.arange(1, 3001)
    np.testing.assert_array_equal(topics[itf.TOPIC_STATE].column('round_trip'), expected)
    np.testing.assert_array_equal(topics[itf.TOPIC_SIM_TRUTH].column('round_trip'), expected)
    np.testing.assert_array_equal(topics[itf.TOPIC_OBJECTIVE].column('O'),
                                  topics[itf.TOPIC_STATE].column('O'))
    assert (np.diff(topics[itf.TOPIC_STATE].timestamps_ns) > 0).all()
    meta = read_metadata(bag)
    counts = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert all(counts[t]['message_count'] == 3000 for t in STREAMS)
    offered = counts[itf.TOPIC_STATE]['topic_metadata']['offered_qos_profiles']
    assert [(q['reliability'], q['durability']) for q in offered] == [('reliable', 'volatile')]
    assert f'wrote {meta["message_count"]} messages to {bag}' in log
    assert f'{itf.TOPIC_STATE} 3000' in log


def test_a_killed_recorder_leaves_a_bag_that_repair_restores(ros_env, tmp_path):
    bag = tmp_path / 'killed'
    recorder = NodeProcess(RECORDER, ros_env, tmp_path / 'recorder.log', '-p', f'output:={bag}')
    laser = _laser_sim(ros_env, tmp_path, 1_000_000)
    try:
        _wait(lambda: flushed_counts(bag)[itf.TOPIC_STATE] >= 1500, 120,
              '1500 states on disk', recorder, laser)
        recorder.proc.send_signal(signal.SIGKILL)
        recorder.proc.wait(10)
    finally:
        laser.stop()
        recorder.stop()
    assert recorder.proc.returncode == -signal.SIGKILL
    with pytest.raises(BagError, match='repair'):
        read_bag(bag)
    report = repair(bag)
    assert report.rewritten and report.files[0].chunks >= 1
    topics = read_bag(bag)
    states = topics[itf.TOPIC_STATE].column('round_trip')
    assert len(states) >= 1500
    np.testing.assert_array_equal(states, np.arange(1, len(states) + 1))
    truths = topics[itf.TOPIC_SIM_TRUTH].column('round_trip')
    np.testing.assert_array_equal(truths, np.arange(1, len(truths) + 1))
    assert abs(len(truths) - len(states)) <= 1
    assert read_metadata(bag)['message_count'] == report.message_count


def test_an_existing_output_stops_the_recorder_with_one_clear_message(ros_env, tmp_path):
    (tmp_path / 'taken').mkdir()
    recorder = NodeProcess(RECORDER, ros_env, tmp_path / 'recorder.log', '-p',
                           f'output:={tmp_path / "taken"}')
    try:
        assert recorder.proc.wait(60) == 2
    except subprocess.TimeoutExpired:
        recorder.stop()
        raise
    log = recorder.output()
    assert 'cannot start' in log and 'exists already' in log and 'Traceback' not in log
