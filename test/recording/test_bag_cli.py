"""dlmpc-bag info / repair / csv on bags written here (no ROS graph)."""

from __future__ import annotations

import csv
import json
import math
import os

import numpy as np
import pytest

from dlmpc_ros import interfaces as itf
from dlmpc_ros.cli.bag import main
from dlmpc_ros.recording import BagWriter, read_bag
from dlmpc_ros.recording.run_csv import read_run_csv
from test.recording.bagutil import serialize, state, write_run

TOPICS = (itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE)


def _writer(path):
    writer = BagWriter(path)
    for topic in TOPICS:
        writer.add_topic(topic)
    return writer


def test_info_lists_topics_and_the_round_trip_gaps(tmp_path, capsys):
    with _writer(tmp_path / 'run') as writer:
        write_run(writer, [*range(1, 51), *range(61, 101)])
        writer.write(itf.TOPIC_STATE, serialize(itf.STATE_FIELDS, state(100)), 2 * 10**18)
    assert main(['info', str(tmp_path / 'run')]) == 0
    out = capsys.readouterr().out
    assert 'metadata version 9' in out and 'ros_distro jazzy' in out
    assert 'messages:   271' in out
    assert f'{itf.TOPIC_STATE}             91  std_msgs/msg/Float64MultiArray' in out
    assert ('/laser/state round trips: 1 .. 100 in 91 messages: 10 missing in 1 gaps, '
            '1 duplicates') in out
    assert 'missing 51..60 (10)' in out


def test_csv_has_the_bringup_run_columns_and_joins_k_by_round_trip(tmp_path, capsys):
    with _writer(tmp_path / 'run') as writer:
        write_run(writer, range(1, 21))
        # A state whose true K never came: K is NaN, as in the bringup's CSV.
        writer.write(itf.TOPIC_STATE, serialize(itf.STATE_FIELDS, state(21)), 2 * 10**18)
    out = tmp_path / 'csv' / 'run.csv'
    assert main(['csv', str(tmp_path / 'run'), str(out)]) == 0
    assert 'wrote 21 rows' in capsys.readouterr().out
    with open(out) as handle:
        header = next(csv.reader(handle))
    assert header == [*itf.STATE_FIELDS, 'K']
    columns = read_run_csv(out)
    np.testing.assert_array_equal(columns['round_trip'], np.arange(1, 22))
    np.testing.assert_array_equal(columns['K'][:20], 0.01 * np.arange(1, 21))
    assert math.isnan(columns['K'][20])
    states = read_bag(tmp_path / 'run')[itf.TOPIC_STATE]
    np.testing.assert_array_equal(columns['M'], states.column('M'))


def test_repair_command_and_errors_on_an_unfinished_bag(tmp_path, capsys):
    bag = tmp_path / 'run'
    with _writer(bag) as writer:
        write_run(writer, range(1, 3001))
    (bag / 'metadata.yaml').unlink()
    mcap = bag / 'run.mcap'
    os.truncate(mcap, mcap.stat().st_size // 2)
    assert main(['info', str(bag)]) == 1
    assert 'dlmpc-bag repair' in capsys.readouterr().err
    assert main(['repair', str(bag)]) == 0
    out = capsys.readouterr().out
    assert 'unfinished; rewrote' in out and 'metadata.yaml' in out
    assert main(['info', str(bag)]) == 0
    assert 'contiguous' in capsys.readouterr().out
    assert main(['repair', str(tmp_path / 'nothing')]) == 1
    assert 'not a bag directory' in capsys.readouterr().err


def test_a_laser_bag_without_true_k_gets_the_measured_metrics(tmp_path, capsys):
    """A real laser publishes no /laser/sim_truth: dlmpc-evaluate --bag reports what needs
    no K, and reads a status topic whose messages differ in length (NaN-padded)."""
    from dlmpc_ros.cli.evaluate import main as evaluate
    from dlmpc_ros.paths import models_dir

    fields = (*itf.CONTROLLER_STATUS_FIELDS, *(f'predicted_O{i}' for i in range(1, 4)))
    with BagWriter(tmp_path / 'bench-run') as writer:
        for topic in (itf.TOPIC_STATE, itf.TOPIC_CONTROLLER_STATUS):
            writer.add_topic(topic)
        for r in range(1, 101):
            writer.write(itf.TOPIC_STATE, serialize(itf.STATE_FIELDS, state(r)), 10**18 + r)
            if r % 10 == 0:  # inner loop (8 values) and outer loop (8 + 3) alternate
                status = [r, float(r % 20 == 0), -1, 3, 0.5, 0.1, 1, 0]
                extra = [0.13, 0.14, 0.15] if r % 20 == 0 else []
                writer.write(itf.TOPIC_CONTROLLER_STATUS,
                             serialize(fields[:8 + len(extra)], status + extra), 10**18 + r)
    status = read_bag(tmp_path / 'bench-run')[itf.TOPIC_CONTROLLER_STATUS]
    assert status.data.shape == (10, 11)
    assert np.isnan(status.data[0, 8:]).all() and status.data[1, 8] == 0.13
    out = tmp_path / 'eval'
    assert evaluate(['--bag', str(tmp_path / 'bench-run'), '--out', str(out),
                     '--models-dir', str(models_dir())]) == 0
    assert 'oracle ratio n/a' in capsys.readouterr().out
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['mean_O'] == pytest.approx(4.0 / 30.0)
    assert metrics['oracle_ratio'] is None and metrics['round_trips_without_K'] == 100
    assert metrics['control_periods'] == 10 and metrics['step_latency_ms_median'] == 0.5
    assert metrics['mode_fractions'] == {'inner': 0.5, 'outer': 0.5}


def test_evaluate_bag_rejects_a_bag_without_laser_state(tmp_path, capsys):
    from dlmpc_ros.cli.evaluate import main as evaluate

    with BagWriter(tmp_path / 'empty') as writer:
        writer.add_topic(itf.TOPIC_OBJECTIVE)
    assert evaluate(['--bag', str(tmp_path / 'empty'), '--out', str(tmp_path / 'eval')]) == 1
    assert 'has no /laser/state' in capsys.readouterr().err


def test_csv_keeps_a_bag_with_foreign_messages_and_says_how_many_it_skipped(tmp_path, capsys):
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    foreign = bytes(store.serialize_cdr(store.types['std_msgs/msg/String'](data='hello'),
                                        'std_msgs/msg/String'))
    with _writer(tmp_path / 'run') as writer:
        write_run(writer, range(1, 11))
        writer.write(itf.TOPIC_STATE, foreign, 2 * 10**18)
        writer.write(itf.TOPIC_STATE, serialize(('x', 'y'), [1.0, 2.0]), 2 * 10**18 + 1)
    out = tmp_path / 'csv' / 'run.csv'
    assert main(['csv', str(tmp_path / 'run'), str(out)]) == 0
    text = capsys.readouterr().out
    assert 'wrote 10 rows' in text and 'skipped 2 messages that do not fit (/laser/state 2)' \
        in text
    np.testing.assert_array_equal(read_run_csv(out)['round_trip'], np.arange(1, 11))
