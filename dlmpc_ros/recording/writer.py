"""Bag writer: serialized CDR messages in, a ROS 2 Jazzy rosbag2 bag (MCAP storage) out.

A bag is a directory ``NAME/`` holding ``NAME/NAME.mcap`` (MCAP profile ``ros2``, schema
encoding ``ros2msg``, message encoding ``cdr``; written by ``rosbags``) and
``NAME/metadata.yaml`` (rosbag2 metadata version 9, as Jazzy writes it). Messages are
taken as the CDR bytes a raw subscription delivers, never deserialized. Timestamps are
receive times in nanoseconds since the epoch.

Crash safety: messages collect in an open MCAP chunk that is closed, written and flushed
to the operating system every ``chunk_messages`` messages or ``flush_period`` seconds,
whichever comes first (and on :meth:`BagWriter.flush`). A writer killed with SIGKILL
leaves an MCAP without summary or footer, and no ``metadata.yaml``; everything up to its
last closed chunk is recovered by :func:`dlmpc_ros.recording.repair.repair`.
"""

from __future__ import annotations

import os
import time
from io import BytesIO
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import yaml
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.rosbag2.storage_mcap import Channel, McapWriter, write_channel, write_string
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

FLOAT64_MULTI_ARRAY = 'std_msgs/msg/Float64MultiArray'
#: rosbag2 metadata version written by ROS 2 Jazzy (offered QoS profiles as a YAML list).
METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
STORAGE_IDENTIFIER = 'mcap'
SERIALIZATION_FORMAT = 'cdr'
METADATA_FILE = 'metadata.yaml'
#: ``RMW_DURATION_INFINITE`` in nanoseconds: what Jazzy's middleware reports for "no limit".
INFINITE_NS = 2**63 - 1
#: Starting time rosbag2 and rosbags give a bag without messages.
NO_MESSAGES_START_NS = 2**63 - 1


class BagError(ValueError):
    """A bag that cannot be written, read or repaired as asked."""


@lru_cache(maxsize=1)
def jazzy_typestore() -> Typestore:
    """The ROS 2 Jazzy message types (message definitions and type hashes) of rosbags."""
    return get_typestore(Stores.ROS2_JAZZY)


def type_description(msgtype: str, msgdef: str | None = None,
                     type_hash: str | None = None) -> tuple[str, str]:
    """The ``ros2msg`` definition and ``RIHS01_`` type hash of a message type.

    Jazzy's own types come from rosbags' Jazzy typestore (``msgdef`` and ``type_hash`` are
    then ignored); other types need ``msgdef``, from which a missing hash is computed.
    """
    store = jazzy_typestore()
    if msgtype in store.types:
        return store.generate_msgdef(msgtype, ros_version=2)[0], store.hash_rihs01(msgtype)
    if not msgdef:
        raise BagError(f'{msgtype} is not a ROS 2 Jazzy type and has no message definition')
    if not type_hash:
        try:
            own = get_typestore(Stores.EMPTY)
            own.register(get_types_from_msg(msgdef, msgtype))
            type_hash = own.hash_rihs01(msgtype)
        except Exception as err:  # rosbags raises several types for a bad definition
            raise BagError(f'cannot parse the definition of {msgtype}: {err}') from None
    return msgdef, type_hash


def _qos_time(ns: int) -> QosTime:
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return QosTime(sec, nsec)


def make_qos(history: int | str = 'unknown', depth: int = 0,
             reliability: int | str = 'reliable', durability: int | str = 'volatile',
             deadline_ns: int = INFINITE_NS, lifespan_ns: int = INFINITE_NS,
             liveliness: int | str = 'automatic',
             liveliness_lease_duration_ns: int = INFINITE_NS,
             avoid_ros_namespace_conventions: bool = False) -> Qos:
    """One offered QoS profile as recorded in a bag.

    Policies are rmw enum values (equal to rclpy's ``HistoryPolicy`` etc. values) or their
    lower-case names (``'keep_last'``, ``'best_effort'``, ...). The defaults are what
    Jazzy reports for a publisher with io.py's reliable, volatile profiles: history
    ``unknown`` with depth 0 (DDS does not share them), infinite durations.
    """
    def policy(enum, value):
        try:
            return enum(value) if isinstance(value, int) else enum[value.upper()]
        except (KeyError, ValueError):
            raise BagError(f'{value!r} is not a {enum.__name__} policy') from None

    return Qos(policy(QosHistory, history), int(depth), policy(QosReliability, reliability),
               policy(QosDurability, durability), _qos_time(deadline_ns),
               _qos_time(lifespan_ns), policy(QosLiveliness, liveliness),
               _qos_time(liveliness_lease_duration_ns), bool(avoid_ros_namespace_conventions))


@dataclass
class TopicRecord:
    """What a bag's metadata says about one topic."""

    name: str
    msgtype: str
    offered_qos: list[Qos] = field(default_factory=list)
    #: ``RIHS01_...`` hash of the message type description.
    type_hash: str = ''
    count: int = 0


def bag_metadata(file_name: str, topics: Iterable[TopicRecord], start_ns: int,
                 end_ns: int) -> dict:
    """The ``metadata.yaml`` content of a one-file MCAP bag, field for field as Jazzy.

    Parameters
    ----------
    file_name
        The MCAP file, relative to the bag directory.
    topics
        Topics with their message counts.
    start_ns, end_ns
        Earliest and latest receive time [ns]; a bag without messages gives
        ``start_ns > end_ns``.
    """
    topics = list(topics)
    count = sum(t.count for t in topics)
    start = start_ns if count else NO_MESSAGES_START_NS
    duration = max(0, end_ns - start_ns) if count else 0
    return {'rosbag2_bagfile_information': {
        'version': METADATA_VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.msgtype,
                                'serialization_format': SERIALIZATION_FORMAT,
                                'offered_qos_profiles': dump_qos_v9(list(t.offered_qos)),
                                'type_description_hash': t.type_hash},
             'message_count': t.count}
            for t in topics],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': None,
        'ros_distro': ROS_DISTRO,
    }}


def write_metadata(bag_dir: str | os.PathLike, metadata: dict) -> Path:
    """Write ``metadata.yaml`` atomically (a reader never sees half a file)."""
    path = Path(bag_dir) / METADATA_FILE
    tmp = path.with_name(METADATA_FILE + '.tmp')
    tmp.write_text(yaml.safe_dump(metadata, sort_keys=False, default_flow_style=False),
                   encoding='utf-8')
    os.replace(tmp, path)
    return path


class _JazzyMcapWriter(McapWriter):
    """rosbags' MCAP storage with Jazzy's channel metadata and embedded bag metadata.

    Jazzy's ``rosbag2_storage_mcap`` gives each channel the metadata keys
    ``offered_qos_profiles`` and ``topic_type_hash`` (rosbags writes only the first), and
    stores the bag metadata in a ``rosbag2`` metadata record (rosbags names the distro
    ``rosbags``; :class:`BagWriter` hands in the Jazzy text as ``serialized_metadata``).
    """

    serialized_metadata: str | None = None

    def add_connection(self, connection, offered_qos_profiles: str) -> None:
        metadata = BytesIO()
        for key, value in (('offered_qos_profiles', offered_qos_profiles),
                           ('topic_type_hash', connection.digest)):
            write_string(metadata, key)
            write_string(metadata, value)
        self.channels.append(Channel(connection.id, connection.msgtype, connection.topic,
                                     connection.ext.serialization_format,
                                     metadata.getvalue()))
        self.channel_stats[connection.id] = 0
        write_channel(self.chunk.bio, self.channels[-1], self.schemas)

    def close(self, version: int, metadata: str) -> None:
        super().close(version, self.serialized_metadata or metadata)


class _Writer(Writer):
    STORAGE_PLUGINS = {StoragePlugin.MCAP: _JazzyMcapWriter}


class BagWriter:
    """Write serialized messages into a new rosbag2 bag (usable as a context manager).

    Parameters
    ----------
    path
        Bag directory to create; it must not exist.
    chunk_messages
        Close and flush the open MCAP chunk after this many messages.
    flush_period
        ... or when a message arrives this many seconds after the last flush.
    clock
        Monotonic time source in seconds.
    """

    def __init__(self, path: str | os.PathLike, *, chunk_messages: int = 4096,
                 flush_period: float = 0.5,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if chunk_messages < 1:
            raise BagError(f'chunk_messages must be >= 1, got {chunk_messages}')
        if not flush_period > 0:
            raise BagError(f'flush_period must be > 0 s, got {flush_period}')
        self.path = Path(path)
        self.chunk_messages = int(chunk_messages)
        self.flush_period = float(flush_period)
        self._clock = clock
        try:
            writer = _Writer(self.path, version=METADATA_VERSION,
                             storage_plugin=StoragePlugin.MCAP)
            writer.open()
        except (WriterError, OSError) as err:
            raise BagError(str(err)) from None
        self._writer: Writer | None = writer
        self._storage = writer.storage
        self.mcap_path = Path(self._storage.path)
        self._connections: dict = {}
        self._records: dict[str, TopicRecord] = {}
        self._write = writer.write
        self._span = (0, 0)
        self._pending = 0
        jazzy_typestore()  # built now (~0.2 s), not while the first messages wait
        self._next_flush = clock() + self.flush_period

    @property
    def closed(self) -> bool:
        return self._writer is None

    @property
    def topics(self) -> tuple[str, ...]:
        """Topics added so far, in order."""
        return tuple(self._records)

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic so far."""
        if self._writer is None:
            return {name: r.count for name, r in self._records.items()}
        counts = self._writer.counts
        return {name: counts[c.id] for name, c in self._connections.items()}

    def add_topic(self, topic: str, msgtype: str = FLOAT64_MULTI_ARRAY,
                  offered_qos: Sequence[Qos] = (), *, msgdef: str | None = None,
                  type_hash: str | None = None) -> None:
        """Add a topic before writing its messages.

        Parameters
        ----------
        topic, msgtype
            Topic name and message type (``pkg/msg/Type``).
        offered_qos
            QoS profiles of the topic's publishers (see :func:`make_qos`).
        msgdef, type_hash
            ``ros2msg`` definition (dependencies appended) and ``RIHS01_`` hash of a type
            that is not one of Jazzy's; both come from the Jazzy typestore otherwise, and
            the hash is computed from ``msgdef`` if not given.
        """
        if self._writer is None:
            raise BagError(f'bag {self.path} is closed')
        if topic in self._connections:
            raise BagError(f'topic {topic} was added already')
        msgdef, type_hash = type_description(msgtype, msgdef, type_hash)
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, msgdef=msgdef, rihs01=type_hash,
            serialization_format=SERIALIZATION_FORMAT, offered_qos_profiles=list(offered_qos))
        self._records[topic] = TopicRecord(topic, msgtype, list(offered_qos), type_hash)

    def write(self, topic: str, data: bytes | memoryview, timestamp_ns: int) -> None:
        """Append one CDR-serialized message of an added topic, received at ``timestamp_ns``."""
        try:
            connection = self._connections[topic]
        except KeyError:
            raise BagError(f'topic {topic} was not added to {self.path}') from None
        self._write(connection, timestamp_ns, data)
        self._pending += 1
        if self._pending >= self.chunk_messages or self._clock() >= self._next_flush:
            self.flush()

    def flush(self) -> None:
        """Close the open chunk (if it holds messages) and hand the file to the OS."""
        if self._writer is None:
            return
        if self._storage.chunk.msgs:
            self._storage.close_chunk()
        self._storage.bio.flush()
        self._pending = 0
        self._next_flush = self._clock() + self.flush_period

    def close(self) -> None:
        """Finish the MCAP (summary, footer) and write ``metadata.yaml``; idempotent."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        for name, connection in self._connections.items():
            self._records[name].count = writer.counts[connection.id]
        self._span = (writer.min_timestamp, writer.max_timestamp)
        metadata = self.metadata()
        self._storage.serialized_metadata = yaml.safe_dump(
            metadata['rosbag2_bagfile_information'], sort_keys=False, default_flow_style=False)
        writer.close()
        write_metadata(self.path, metadata)

    def metadata(self, file_name: str | None = None) -> dict:
        """The bag's ``metadata.yaml`` content so far (see :func:`bag_metadata`).

        ``file_name`` replaces the MCAP file's name, for a file that is moved.
        """
        if self._writer is not None:
            counts = self.counts
            for name, record in self._records.items():
                record.count = counts[name]
            self._span = (self._writer.min_timestamp, self._writer.max_timestamp)
        return bag_metadata(file_name or self.mcap_path.name, self._records.values(),
                            *self._span)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = 'closed' if self.closed else 'open'
        return f'BagWriter({str(self.path)!r}, {state}, {sum(self.counts.values())} messages)'
