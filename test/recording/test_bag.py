"""Bag writer, reader and repair without ROS: the files a Jazzy rosbag2 reads."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording import (
    FLOAT64_MULTI_ARRAY,
    BagError,
    BagWriter,
    check_round_trips,
    make_qos,
    read_bag,
    read_metadata,
    repair,
)
from dlmpc_ros.recording.reader import decode_float64_arrays
from dlmpc_ros.recording.repair import resume
from dlmpc_ros.recording.writer import jazzy_typestore
from test.recording.bagutil import flushed_counts, serialize, state, write_run

ROOT = Path(__file__).resolve().parents[2]
INFINITE = {'sec': 9223372036, 'nsec': 854775807}
#: What Jazzy's recorder stores for a publisher of io.py's STREAM_QOS (reported by rmw).
STREAM_OFFER = {'history': 'unknown', 'depth': 0, 'reliability': 'reliable',
                'durability': 'volatile', 'deadline': INFINITE, 'lifespan': INFINITE,
                'liveliness': 'automatic', 'liveliness_lease_duration': INFINITE,
                'avoid_ros_namespace_conventions': False}
JAZZY_HASH = 'RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f'


def _bag(path: Path, round_trips=range(1, 101), **options) -> Path:
    with BagWriter(path, **options) as writer:
        for topic in (itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE):
            writer.add_topic(topic, FLOAT64_MULTI_ARRAY, [make_qos()])
        writer.add_topic('/laser/unused', FLOAT64_MULTI_ARRAY,
                         [make_qos('keep_last', 5, 'best_effort', 'transient_local',
                                   deadline_ns=1_500_000_000)])
        write_run(writer, round_trips)
    return path


def test_metadata_is_rosbag2_version_9_as_jazzy_writes_it(tmp_path):
    bag = _bag(tmp_path / 'run')
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert list(meta) == ['version', 'storage_identifier', 'duration', 'starting_time',
                          'message_count', 'topics_with_message_count', 'compression_format',
                          'compression_mode', 'relative_file_paths', 'files', 'custom_data',
                          'ros_distro']
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['ros_distro'] == 'jazzy' and meta['custom_data'] is None
    assert meta['compression_format'] == '' and meta['compression_mode'] == ''
    assert meta['relative_file_paths'] == ['run.mcap'] and (bag / 'run.mcap').is_file()
    start = 1_700_000_000_000_000_000 + 3000
    assert meta['starting_time'] == {'nanoseconds_since_epoch': start}
    assert meta['duration'] == {'nanoseconds': 99 * 3000 + 2000}
    assert meta['message_count'] == 300
    assert meta['files'] == [{'path': 'run.mcap', 'starting_time': meta['starting_time'],
                              'duration': meta['duration'], 'message_count': 300}]
    topics = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert {name: t['message_count'] for name, t in topics.items()} == {
        itf.TOPIC_SIM_TRUTH: 100, itf.TOPIC_STATE: 100, itf.TOPIC_OBJECTIVE: 100,
        '/laser/unused': 0}
    for t in topics.values():
        assert list(t['topic_metadata']) == ['name', 'type', 'serialization_format',
                                             'offered_qos_profiles', 'type_description_hash']
        assert t['topic_metadata']['type'] == FLOAT64_MULTI_ARRAY
        assert t['topic_metadata']['serialization_format'] == 'cdr'
        assert t['topic_metadata']['type_description_hash'] == JAZZY_HASH
    assert topics[itf.TOPIC_STATE]['topic_metadata']['offered_qos_profiles'] == [STREAM_OFFER]
    assert topics['/laser/unused']['topic_metadata']['offered_qos_profiles'] == [{
        **STREAM_OFFER, 'history': 'keep_last', 'depth': 5, 'reliability': 'best_effort',
        'durability': 'transient_local', 'deadline': {'sec': 1, 'nsec': 500_000_000}}]


def test_mcap_is_the_ros2_profile_with_jazzy_schemas_and_channels(tmp_path):
    bag = _bag(tmp_path / 'run')
    mcap = McapReader(bag / 'run.mcap')  # rosbags' reader: refuses a profile other than ros2
    mcap.open()
    try:
        (schema,) = mcap.schemas.values()
        channels = {c.topic: c for c in mcap.channels.values()}
    finally:
        mcap.close()
    assert schema.name == FLOAT64_MULTI_ARRAY and schema.encoding == 'ros2msg'
    assert schema.data == jazzy_typestore().generate_msgdef(FLOAT64_MULTI_ARRAY,
                                                            ros_version=2)[0]
    # The schema text describes exactly Jazzy's type: its type hash is the one that the
    # Jazzy std_msgs build recorded (share/std_msgs/msg/Float64MultiArray.json).
    own = get_typestore(Stores.EMPTY)
    own.register(get_types_from_msg(schema.data, FLOAT64_MULTI_ARRAY))
    assert own.hash_rihs01(FLOAT64_MULTI_ARRAY) == JAZZY_HASH
    built = Path(sys.prefix) / 'share' / 'std_msgs' / 'msg' / 'Float64MultiArray.json'
    if built.is_file():
        hashes = json.loads(built.read_text())['type_hashes']
        assert hashes[0] == {'type_name': FLOAT64_MULTI_ARRAY, 'hash_string': JAZZY_HASH}
    for channel in channels.values():
        assert channel.message_encoding == 'cdr' and channel.schema == FLOAT64_MULTI_ARRAY
        assert b'offered_qos_profiles' in channel.metadata
        assert b'topic_type_hash' in channel.metadata and JAZZY_HASH.encode() in channel.metadata
    data = (bag / 'run.mcap').read_bytes()
    assert data.startswith(b'\x89MCAP0\r\n') and data.endswith(b'\x89MCAP0\r\n')
    assert b'serialized_metadata' in data and b'ros_distro: jazzy' in data


def test_read_bag_returns_arrays_equal_to_rosbags_deserialization(tmp_path):
    bag = _bag(tmp_path / 'run', range(1, 501))
    topics = read_bag(bag)
    assert set(topics) == {itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE,
                           '/laser/unused'}
    states = topics[itf.TOPIC_STATE]
    assert states.fields == itf.STATE_FIELDS and states.data.shape == (500, 10)
    assert np.array_equal(states.data, np.array([state(r) for r in range(1, 501)]))
    assert np.array_equal(topics[itf.TOPIC_SIM_TRUTH].column('K'),
                          0.01 * np.arange(1, 501))
    assert len(topics['/laser/unused']) == 0
    store = jazzy_typestore()
    with Reader(bag) as reader:
        connections = [c for c in reader.connections if c.topic == itf.TOPIC_STATE]
        reference = [(stamp, store.deserialize_cdr(raw, FLOAT64_MULTI_ARRAY).data)
                     for _, stamp, raw in reader.messages(connections=connections)]
    assert states.timestamps_ns.tolist() == [stamp for stamp, _ in reference]
    assert np.array_equal(states.data, np.array([d for _, d in reference]))
    assert check_round_trips(states.column('round_trip')).contiguous


def test_decoding_handles_mixed_layouts_widths_and_nan():
    raws = [serialize(('a', 'b'), [1.0, np.nan]), serialize(('ab',), [3.0]),
            serialize(('a', 'b'), [5.0, -np.inf])]
    fields, data, keep = decode_float64_arrays(raws)
    assert fields == ('a', 'b') and keep.tolist() == [True, False, True]
    np.testing.assert_array_equal(data, [[1.0, np.nan], [5.0, -np.inf]])
    # messages of different lengths whose fields extend each other (the controller's
    # status with and without the predicted O): the shorter ones are padded with NaN
    fields, data, keep = decode_float64_arrays([serialize(('a',), [1.0]),
                                                serialize(('a', 'b'), [1.0, 2.0])])
    np.testing.assert_array_equal(data, [[1.0, np.nan], [1.0, 2.0]])
    assert fields == ('a', 'b') and keep.all()


def test_messages_that_do_not_fit_their_topic_are_skipped_and_counted(tmp_path):
    """A std_msgs/String published on a Float64MultiArray topic, or a message of another
    layout, once made the whole bag unreadable ("messages of equal size hold different
    numbers of values"): now it is left out, counted, and the rest is kept."""
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_JAZZY)
    foreign = bytes(store.serialize_cdr(store.types['std_msgs/msg/String'](data='x' * 21),
                                        'std_msgs/msg/String'))
    good = [serialize(itf.ANGLE_FIELDS, [0.1 * i, 0.0, 0.0, 0.0]) for i in range(5)]
    other = serialize(('x', 'y', 'z', 'w'), [9.0, 9.0, 9.0, 9.0])
    fields, data, keep = decode_float64_arrays([*good[:2], foreign, other, *good[2:]])
    assert fields == itf.ANGLE_FIELDS
    assert keep.tolist() == [True, True, False, False, True, True, True]
    np.testing.assert_allclose(data[:, 0], [0.0, 0.1, 0.2, 0.3, 0.4])


def test_complete_chunks_reach_the_disk_while_the_bag_is_open(tmp_path):
    now = [0.0]
    bag = tmp_path / 'open'
    writer = BagWriter(bag, chunk_messages=90, flush_period=0.5, clock=lambda: now[0])
    for topic in (itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE):
        writer.add_topic(topic)
    write_run(writer, range(1, 71))  # 210 messages: two chunks of 90, 30 pending
    assert sum(flushed_counts(bag).values()) == 180
    now[0] = 0.6  # the flush period has passed: the next message closes the chunk
    write_run(writer, [71])
    assert sum(flushed_counts(bag).values()) == 211
    write_run(writer, [72])
    writer.flush()  # what the recorder's timer does when no message comes
    assert sum(flushed_counts(bag).values()) == 216
    assert not (bag / 'metadata.yaml').exists()
    writer.close()
    assert read_metadata(bag)['message_count'] == 216


KILLED_WRITER = '''
import os, signal, sys
from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording import BagWriter
from test.recording.bagutil import write_run
writer = BagWriter(sys.argv[1], chunk_messages=300)
for topic in (itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE):
    writer.add_topic(topic)
write_run(writer, range(1, 451))  # 1350 messages: 4 chunks of 300 flushed, 150 pending
os.kill(os.getpid(), signal.SIGKILL)
'''


def test_repair_recovers_the_flushed_prefix_of_a_killed_writer(tmp_path):
    bag = tmp_path / 'killed'
    proc = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(bag)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert not (bag / 'metadata.yaml').exists()
    with pytest.raises(BagError, match='dlmpc-bag repair'):
        read_bag(bag)
    report = repair(bag)
    [file] = report.files
    assert file.rewritten and not file.finished and file.chunks == 4
    assert report.counts == {itf.TOPIC_SIM_TRUTH: 400, itf.TOPIC_STATE: 400,
                             itf.TOPIC_OBJECTIVE: 400}
    topics = read_bag(bag)
    assert topics[itf.TOPIC_STATE].column('round_trip').tolist() == list(range(1, 401))
    assert read_metadata(bag)['message_count'] == 1200
    assert sorted(p.name for p in bag.iterdir()) == ['killed.mcap', 'metadata.yaml']
    again = repair(bag)  # now a finished bag: nothing to rewrite
    assert again.files[0].finished and not again.rewritten and again.counts == report.counts


def test_a_resumed_bag_continues_in_new_files_and_reads_as_one(tmp_path):
    """A recorder restarted after a kill once refused its bag ("exists already"): now the
    bag is repaired and continued in a new file, as rosbag2 splits a bag."""
    bag = tmp_path / 'killed'
    proc = subprocess.run([sys.executable, '-c', KILLED_WRITER, str(bag)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    writer, report = resume(bag, chunk_messages=300)
    assert [f.rewritten for f in report.files] == [True] and report.message_count == 1200
    with writer:
        for topic in (itf.TOPIC_SIM_TRUTH, itf.TOPIC_STATE, itf.TOPIC_OBJECTIVE):
            writer.add_topic(topic)
        writer.add_topic('/laser/new')  # a topic that only the second file has
        write_run(writer, range(451, 601))
        writer.write('/laser/new', serialize(('x',), [1.0]), 1_800_000_000_000_000_000)
    assert writer.mcap_path.name == 'killed_1.mcap'
    writer, report = resume(bag)  # a second restart, after a clean stop this time
    assert not report.rewritten and len(report.files) == 2
    with writer:
        writer.add_topic(itf.TOPIC_STATE)
        for r in range(601, 611):
            writer.write(itf.TOPIC_STATE, serialize(itf.STATE_FIELDS, state(r)),
                         1_900_000_000_000_000_000 + r)
    meta = read_metadata(bag)
    assert meta['relative_file_paths'] == ['killed.mcap', 'killed_1.mcap', 'killed_2.mcap']
    assert [f['message_count'] for f in meta['files']] == [1200, 451, 10]
    assert meta['message_count'] == 1661
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in meta['topics_with_message_count']}
    assert counts == {itf.TOPIC_SIM_TRUTH: 550, itf.TOPIC_STATE: 560,
                      itf.TOPIC_OBJECTIVE: 550, '/laser/new': 1}
    # the project's reader and rosbags' own both read the files as one bag, in order
    states = read_bag(bag)[itf.TOPIC_STATE].column('round_trip').tolist()
    assert states == list(range(1, 401)) + list(range(451, 611))
    check = check_round_trips(np.array(states))
    assert check.gaps == ((401, 450),)
    with Reader(bag) as reader:
        assert reader.message_count == 1661
        assert sum(1 for c, _, _ in reader.messages() if c.topic == itf.TOPIC_STATE) == 560
    # the repair of a bag of several files leaves it as it is
    assert repair(bag).counts == counts and read_metadata(bag) == meta


def test_a_bag_with_a_killed_continuation_is_repaired_file_by_file(tmp_path):
    bag = _bag(tmp_path / 'run', range(1, 101))
    script = KILLED_WRITER.replace(
        'writer = BagWriter(sys.argv[1], chunk_messages=300)',
        'from dlmpc_ros.recording.repair import resume\n'
        'writer, _ = resume(sys.argv[1], chunk_messages=300)').replace(
        'range(1, 451)', 'range(101, 551)')
    proc = subprocess.run([sys.executable, '-c', script, str(bag)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    report = repair(bag)
    assert [(f.mcap.name, f.rewritten) for f in report.files] == [('run.mcap', False),
                                                                  ('run_1.mcap', True)]
    states = read_bag(bag)[itf.TOPIC_STATE].column('round_trip').tolist()
    assert states == list(range(1, 501))


def test_repair_drops_a_chunk_cut_in_the_middle_and_rebuilds_lost_metadata(tmp_path):
    original = _bag(tmp_path / 'run', range(1, 2001), chunk_messages=1000)
    expected = read_metadata(original)
    cut = tmp_path / 'cut'
    shutil.copytree(original, cut)
    (cut / 'metadata.yaml').unlink()
    report = repair(cut)  # a finished MCAP: only metadata.yaml is rebuilt
    assert report.files[0].finished and not report.rewritten
    rebuilt = read_metadata(cut)
    assert rebuilt == {**expected, 'relative_file_paths': ['run.mcap'],
                       'files': [{**expected['files'][0], 'path': 'run.mcap'}]}
    mcap = cut / 'run.mcap'
    os.truncate(mcap, mcap.stat().st_size * 2 // 3)  # inside the fifth of six chunks
    (cut / 'metadata.yaml').unlink()
    report = repair(cut)
    [file] = report.files
    assert file.rewritten and file.chunks == 4 and file.dropped_bytes > 0
    states = read_bag(cut)[itf.TOPIC_STATE]
    assert states.column('round_trip').tolist() == list(range(1, 1334))


def test_errors_name_the_problem(tmp_path):
    bag = _bag(tmp_path / 'run')
    with pytest.raises(BagError, match='exists'):
        BagWriter(bag)
    with pytest.raises(BagError, match='no topic /nope'):
        read_bag(bag, ['/nope'])
    with pytest.raises(BagError, match='not a bag directory'):
        repair(tmp_path / 'missing')
    with BagWriter(tmp_path / 'other') as writer:
        with pytest.raises(BagError, match='was not added'):
            writer.write('/laser/state', b'', 0)
        with pytest.raises(BagError, match='not a ROS 2 Jazzy type'):
            writer.add_topic('/x', 'my_pkg/msg/Thing')
        with pytest.raises(BagError, match='policy'):
            make_qos(reliability='sometimes')


def test_round_trip_check_counts_gaps_duplicates_and_reordering():
    check = check_round_trips([1, 2, 3, 7, 8, 8, 6, 12])
    assert (check.first, check.last, check.count) == (1, 12, 8)
    assert check.gaps == ((4, 5), (9, 11)) and check.missing == 5
    assert check.duplicates == 1 and check.out_of_order == 1 and not check.contiguous
    assert check_round_trips(range(5, 9)).contiguous
    assert check_round_trips([]).first is None


def test_recording_and_bag_cli_work_without_rclpy(tmp_path):
    bag = _bag(tmp_path / 'run')
    code = ('import sys; sys.modules["rclpy"] = None\n'
            'from dlmpc_ros.recording import read_bag, repair\n'
            'from dlmpc_ros.cli.bag import main\n'
            f'repair({str(bag)!r})\n'
            f'sys.exit(main(["info", {str(bag)!r}]))\n')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    assert '/laser/state round trips: 1 .. 100 in 100 messages, contiguous' in proc.stdout
