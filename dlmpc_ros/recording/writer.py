"""Bag writer: serialized CDR messages in, a ROS 2 Jazzy rosbag2 bag (MCAP storage) out.

A bag is a directory ``NAME/`` holding ``NAME/NAME.mcap`` (MCAP profile ``ros2``, schema
encoding ``ros2msg``, message encoding ``cdr``; written by ``rosbags``) and
``NAME/metadata.yaml`` (rosbag2 metadata version 9, as Jazzy writes it). Messages are
taken as the CDR bytes a raw subscription delivers, never deserialized. Timestamps are
receive times in nanoseconds since the epoch.

A bag may hold several MCAP files, in order (``NAME.mcap``, ``NAME_1.mcap``, ...; as
rosbag2 splits a bag): a recorder restarted after a crash continues the bag in a new file
(:func:`dlmpc_ros.recording.repair.resume`), and ``metadata.yaml`` lists every file.

Crash safety: messages collect in an open MCAP chunk that is closed, written and flushed
to the operating system every ``chunk_messages`` messages or ``flush_period`` seconds,
whichever comes first (and on :meth:`BagWriter.flush`). A writer killed with SIGKILL
leaves an MCAP without summary or footer, and no ``metadata.yaml``; everything up to its
last closed chunk is recovered by :func:`dlmpc_ros.recording.repair.repair`.
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from importlib.metadata import version as package_version
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
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.storage_mcap import (
    Channel,
    McapWriter,
    PendingChunk,
    write_channel,
    write_record,
    write_string,
)
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
#: The magic bytes an MCAP file starts and ends with.
MAGIC = b'\x89MCAP0\r\n'


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


@dataclass(frozen=True)
class FileSpan:
    """One MCAP file of a bag: its name (relative to the bag directory), the earliest and
    latest receive time [ns] of its messages and their count."""

    name: str
    start_ns: int
    end_ns: int
    count: int

    def as_metadata(self) -> dict:
        start = self.start_ns if self.count else NO_MESSAGES_START_NS
        duration = max(0, self.end_ns - self.start_ns) if self.count else 0
        return {'path': self.name, 'starting_time': {'nanoseconds_since_epoch': start},
                'duration': {'nanoseconds': duration}, 'message_count': self.count}


@dataclass(frozen=True)
class BagContents:
    """What the files of a bag written so far hold: the files in order and the topics
    with their message counts over all of them."""

    files: tuple[FileSpan, ...]
    topics: tuple[TopicRecord, ...]


def merge_topics(parts: Iterable[Iterable[TopicRecord]]) -> list[TopicRecord]:
    """Topics of several files of one bag, in order of first appearance, with their
    counts summed (QoS and hash of the first file that has the topic); BagError if a
    topic changes its type between files."""
    merged: dict[str, TopicRecord] = {}
    for records in parts:
        for record in records:
            known = merged.get(record.name)
            if known is None:
                merged[record.name] = TopicRecord(record.name, record.msgtype,
                                                  list(record.offered_qos), record.type_hash,
                                                  record.count)
            elif known.msgtype != record.msgtype:
                raise BagError(f'topic {record.name} is {known.msgtype} in one file of the '
                               f'bag and {record.msgtype} in another')
            else:
                known.count += record.count
    return list(merged.values())


def bag_metadata(files: Sequence[FileSpan], topics: Iterable[TopicRecord]) -> dict:
    """The ``metadata.yaml`` content of an MCAP bag, field for field as Jazzy.

    Parameters
    ----------
    files
        The bag's MCAP files in order.
    topics
        Topics with their message counts over all files.
    """
    topics = list(topics)
    count = sum(t.count for t in topics)
    spans = [f for f in files if f.count]
    start_ns = min((f.start_ns for f in spans), default=0)
    end_ns = max((f.end_ns for f in spans), default=0)
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
        'relative_file_paths': [f.name for f in files],
        'files': [f.as_metadata() for f in files],
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

    def __init__(self, path: Path, compression: CompressionMode, file_stem: str = '') -> None:
        """The file ``path/<file_stem>.mcap``; rosbags names it after the directory."""
        if not file_stem or file_stem == path.name:
            super().__init__(path, compression)
            return
        # rosbags' McapWriter.__init__ (rosbags 0.11) with the file named file_stem
        if compression != CompressionMode.NONE:
            raise WriterError('compression is not supported when adding a file to a bag')
        self.path = path / f'{file_stem}.mcap'
        self.bio = self.path.open('xb')
        self.bio.write(MAGIC)
        header = BytesIO()
        write_string(header, 'ros2')
        write_string(header, f'rosbags-{package_version("rosbags")}')
        write_record(self.bio, 0x01, header)
        self.schemas, self.channels, self.chunks = [], [], []
        self.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))
        self.compression, self.compressor = '', lambda data: data
        self.message_start_time, self.message_end_time = 2**63 - 1, 0
        self.channel_stats = {}

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
    """rosbags' bag writer with Jazzy's MCAP storage, creating the bag directory or, with
    ``file_stem`` given, adding a file named so to an existing one."""

    STORAGE_PLUGINS = {StoragePlugin.MCAP: _JazzyMcapWriter}

    def __init__(self, path: Path, file_stem: str = '') -> None:
        self.file_stem = file_stem
        path = Path(path)
        if file_stem:  # rosbags writes only into a new directory: check it ourselves
            if not path.is_dir():
                raise WriterError(f'{path} is not a bag directory to add a file to')
            if (path / f'{file_stem}.mcap').exists():
                raise WriterError(f'{path / file_stem}.mcap exists already, not overwriting.')
            super().__init__(path / f'.{file_stem}', version=METADATA_VERSION,
                             storage_plugin=StoragePlugin.MCAP)
            self.path, self.metapath = path, path / '.rosbags-metadata.yaml'
        else:
            super().__init__(path, version=METADATA_VERSION, storage_plugin=StoragePlugin.MCAP)

    def open(self) -> None:
        if not self.file_stem:
            super().open()
            return
        self.storage = _JazzyMcapWriter(self.path, self.compression_mode, self.file_stem)

    def close(self) -> None:
        super().close()
        if self.file_stem:  # rosbags' own one-file metadata; BagWriter writes the real one
            self.metapath.unlink(missing_ok=True)


class BagWriter:
    """Write serialized messages into a new rosbag2 bag, or into a new file of an existing
    one (usable as a context manager).

    Parameters
    ----------
    path
        Bag directory to create; it must not exist unless ``continues`` is given.
    continues
        What the bag at ``path`` holds already (see
        :func:`dlmpc_ros.recording.repair.resume`): the messages go to a new file
        ``<name>_<k>.mcap`` after its ``k`` files, and ``metadata.yaml`` lists them all.
    chunk_messages
        Close and flush the open MCAP chunk after this many messages.
    flush_period
        ... or when a message arrives this many seconds after the last flush.
    clock
        Monotonic time source in seconds.
    """

    def __init__(self, path: str | os.PathLike, *, continues: BagContents | None = None,
                 chunk_messages: int = 4096, flush_period: float = 0.5,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if chunk_messages < 1:
            raise BagError(f'chunk_messages must be >= 1, got {chunk_messages}')
        if not flush_period > 0:
            raise BagError(f'flush_period must be > 0 s, got {flush_period}')
        self.path = Path(path)
        self.chunk_messages = int(chunk_messages)
        self.flush_period = float(flush_period)
        self._clock = clock
        self.continues = continues or BagContents((), ())
        stem = f'{self.path.name}_{len(continues.files)}' if continues is not None else ''
        try:
            writer = _Writer(self.path, stem)
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
            QoS profiles of the topic's publishers (see :func:`make_qos`); a topic that the
            earlier files of a continued bag hold keeps the profiles recorded there.
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
        earlier = next((r for r in self.continues.topics if r.name == topic), None)
        if earlier is not None:
            # one topic, one description in every file (readers match files to the
            # metadata by type, hash and QoS): the one the bag's earlier files hold
            if earlier.msgtype != msgtype:
                raise BagError(f'topic {topic} is {earlier.msgtype} in the earlier files of '
                               f'{self.path}, not {msgtype}')
            offered_qos, type_hash = earlier.offered_qos, earlier.type_hash or type_hash
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

        ``file_name`` replaces the MCAP file's name, for a file that is moved. The files
        and topics of ``continues`` come first.
        """
        if self._writer is not None:
            counts = self.counts
            for name, record in self._records.items():
                record.count = counts[name]
            self._span = (self._writer.min_timestamp, self._writer.max_timestamp)
        own = self._records.values()
        span = FileSpan(file_name or self.mcap_path.name, *self._span,
                        sum(r.count for r in own))
        return bag_metadata((*self.continues.files, span),
                            merge_topics([self.continues.topics, own]))

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        state = 'closed' if self.closed else 'open'
        return f'BagWriter({str(self.path)!r}, {state}, {sum(self.counts.values())} messages)'
