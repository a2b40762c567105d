"""Repair a bag whose recorder died, and continue a bag in a new file.

A recorder killed with SIGKILL leaves an MCAP file that ends after its last flushed chunk
(possibly inside a chunk it was writing), with no summary section and no footer, and no
up-to-date ``metadata.yaml``. ROS 2 tools and rosbags refuse such a bag. :func:`repair`
reads each unfinished file record by record, keeps every complete (and, where the chunk
has one, CRC-checked) chunk, and rewrites their schemas, channels and messages into a
fresh, finished MCAP that replaces the damaged one; then it writes ``metadata.yaml`` from
what all the bag's files hold. Finished files are left as they are. :func:`resume` repairs
a bag and opens a writer for its next file: how a restarted recorder continues its bag.
"""

from __future__ import annotations

import os
import re
import shutil
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO
from zlib import crc32

from rosbags.rosbag2.metadata import parse_qos

from dlmpc_ros.recording.writer import (
    MAGIC,
    BagContents,
    BagError,
    BagWriter,
    FileSpan,
    TopicRecord,
    bag_metadata,
    merge_topics,
    type_description,
    write_metadata,
)

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END = (
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F)
_FOOTER = struct.Struct('<BQQQI')  # opcode, length, summary start, summary offsets, crc
_RECORD = struct.Struct('<BQ')
_CHUNK = struct.Struct('<QQQI')  # start time, end time, uncompressed size, crc
_MESSAGE = struct.Struct('<HIQQ')  # channel, sequence, log time, publish time


@dataclass
class Channel:
    """An MCAP channel with its schema: one topic of the bag."""

    topic: str
    msgtype: str
    schema_encoding: str
    msgdef: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass
class FileRepair:
    """What :func:`repair` found in one MCAP file of a bag."""

    mcap: Path
    #: The file had its summary and footer (no message lost).
    finished: bool
    #: The file was unfinished and has been rewritten into a finished one.
    rewritten: bool
    #: Complete chunks read.
    chunks: int
    #: Bytes at the end of an unfinished file that could not be read (an incomplete chunk).
    dropped_bytes: int
    #: Messages per topic in the (repaired) file.
    counts: dict[str, int] = field(default_factory=dict)


@dataclass
class RepairReport:
    """What :func:`repair` found and did, file by file, and what the bag holds now."""

    bag: Path
    files: list[FileRepair]
    contents: BagContents

    @property
    def rewritten(self) -> bool:
        return any(f.rewritten for f in self.files)

    @property
    def counts(self) -> dict[str, int]:
        """Messages per topic over all files."""
        return {t.name: t.count for t in self.contents.topics}

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())


class McapScan:
    """Read an MCAP file's data section record by record, tolerating a truncated end.

    Iterating yields ``(Channel, log_time_ns, data)`` for every message, in file order;
    ``channels`` fills as channel records are met. After the iteration, ``finished``,
    ``chunks`` and ``end`` (offset just past the last complete record) are set.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.size = path.stat().st_size
        self.channels: dict[int, Channel] = {}
        self._schemas: dict[int, tuple[str, str, str]] = {}
        self.chunks = 0
        self.end = 0
        self.finished = False

    def has_footer(self) -> bool:
        """The file ends with a footer record and the magic (a closed MCAP)."""
        if self.size < 2 * len(MAGIC) + _FOOTER.size:
            return False
        with self.path.open('rb') as f:
            f.seek(self.size - _FOOTER.size - len(MAGIC))
            tail = f.read()
        op, length = _RECORD.unpack_from(tail)
        return tail.endswith(MAGIC) and op == OP_FOOTER and length == 20

    def __iter__(self) -> Iterator[tuple[Channel, int, bytes]]:
        with self.path.open('rb') as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise BagError(f'{self.path} is not an MCAP file')
            self.end = len(MAGIC)
            yield from self._records(f)
        self.finished = self.finished and self.has_footer()

    def _records(self, f: BinaryIO) -> Iterator[tuple[Channel, int, bytes]]:
        while True:
            head = f.read(_RECORD.size)
            if len(head) < _RECORD.size:
                return
            op, length = _RECORD.unpack(head)
            if self.end + _RECORD.size + length > self.size:
                return  # a record cut off by the kill
            if op in (OP_HEADER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK):
                body = f.read(length)
                if op == OP_HEADER:
                    profile = _string(body, 0)[0]
                    if profile != 'ros2':
                        raise BagError(f'{self.path} has MCAP profile {profile!r}, not ros2')
                elif op == OP_CHUNK:
                    records = self._chunk(body)
                    if records is None:
                        return  # a damaged chunk ends what can be trusted
                    self.chunks += 1
                    yield from self._inner(records)
                else:
                    yield from self._inner(head + body)
            else:
                f.seek(length, os.SEEK_CUR)
            self.end += _RECORD.size + length
            if op == OP_DATA_END:
                self.finished = True
                return

    @staticmethod
    def _chunk(body: bytes) -> bytes | None:
        """The records of a chunk, or None if it does not check out."""
        try:
            _, _, size, crc = _CHUNK.unpack_from(body)
            compression, offset = _string(body, _CHUNK.size)
            (length,) = struct.unpack_from('<Q', body, offset)
            data = body[offset + 8:offset + 8 + length]
            if len(data) != length:
                return None
            records = _decompress(data, compression)
        except (struct.error, ValueError, RuntimeError):
            return None
        if len(records) != size or (crc and crc32(records) != crc):
            return None
        return records

    def _inner(self, records: bytes) -> Iterator[tuple[Channel, int, bytes]]:
        position = 0
        while position + _RECORD.size <= len(records):
            op, length = _RECORD.unpack_from(records, position)
            start = position + _RECORD.size
            position = start + length
            if position > len(records):
                return
            if op == OP_MESSAGE:
                channel_id, _, log_time, _ = _MESSAGE.unpack_from(records, start)
                channel = self.channels.get(channel_id)
                if channel is not None:
                    yield channel, log_time, records[start + _MESSAGE.size:position]
            elif op == OP_SCHEMA:
                (schema_id,) = struct.unpack_from('<H', records, start)
                name, at = _string(records, start + 2)
                encoding, at = _string(records, at)
                data, _ = _string(records, at)
                self._schemas[schema_id] = (name, encoding, data)
            elif op == OP_CHANNEL:
                channel_id, schema_id = struct.unpack_from('<HH', records, start)
                topic, at = _string(records, start + 4)
                encoding, at = _string(records, at)
                name, schema_encoding, msgdef = self._schemas.get(schema_id, ('', '', ''))
                self.channels[channel_id] = Channel(topic, name, schema_encoding, msgdef,
                                                    encoding, _string_map(records, at))


def _string(buffer: bytes, offset: int) -> tuple[str, int]:
    (length,) = struct.unpack_from('<I', buffer, offset)
    end = offset + 4 + length
    if end > len(buffer):
        raise ValueError('string past the end of its record')
    return bytes(buffer[offset + 4:end]).decode('utf-8'), end


def _string_map(buffer: bytes, offset: int) -> dict[str, str]:
    (length,) = struct.unpack_from('<I', buffer, offset)
    position, end = offset + 4, offset + 4 + length
    result = {}
    while position < end:
        key, position = _string(buffer, position)
        result[key], position = _string(buffer, position)
    return result


def _decompress(data: bytes, compression: str) -> bytes:
    if compression == '':
        return data
    if compression == 'zstd':
        from backports import zstd
        return zstd.decompress(data)
    if compression == 'lz4':
        import lz4.frame
        return lz4.frame.decompress(data)
    raise ValueError(f'unsupported chunk compression {compression!r}')


def find_mcaps(bag: Path) -> list[Path]:
    """The MCAP files of a bag directory in recording order: ``NAME.mcap`` (or
    ``NAME_0.mcap``), ``NAME_1.mcap``, ... (rosbag2's split names), then any others by
    name; BagError if there is none."""
    if not bag.is_dir():
        raise BagError(f'{bag} is not a bag directory')

    def order(path: Path) -> tuple[int, str]:
        match = re.fullmatch(re.escape(bag.name) + r'(?:_(\d+))?', path.stem)
        if match is None:
            return 2**31, path.name
        return int(match.group(1) or 0), path.name

    files = sorted(bag.glob('*.mcap'), key=order)
    if not files:
        raise BagError(f'no .mcap file in {bag}')
    return files


def _record(channel: Channel) -> TopicRecord:
    """The metadata of a channel's topic, without messages yet."""
    msgdef = channel.msgdef if channel.schema_encoding == 'ros2msg' else None
    _, type_hash = type_description(channel.msgtype, msgdef,
                                    channel.metadata.get('topic_type_hash'))
    qos = parse_qos(channel.metadata.get('offered_qos_profiles', ''))
    return TopicRecord(channel.topic, channel.msgtype, qos, type_hash)


def repair(bag_dir: str | os.PathLike) -> RepairReport:
    """Make a bag readable again after its recorder was killed.

    Rewrites each unfinished MCAP file (no summary or footer) from its complete chunks into
    a finished one that replaces it, then rebuilds ``metadata.yaml`` from all the files.
    Safe to run on an intact bag (only ``metadata.yaml`` is rewritten).
    """
    bag = Path(bag_dir)
    files, spans, parts = [], [], []
    for mcap in find_mcaps(bag):
        scan = McapScan(mcap)
        rewritten = not scan.has_footer()
        if rewritten:
            chunks, dropped = _rewrite(bag, mcap, scan)
            scan = McapScan(mcap)
        span, records = _contents(mcap, scan)
        files.append(FileRepair(mcap, not rewritten, rewritten,
                                chunks if rewritten else scan.chunks,
                                dropped if rewritten else 0,
                                {r.name: r.count for r in records}))
        spans.append(span)
        parts.append(records)
    contents = BagContents(tuple(spans), tuple(merge_topics(parts)))
    write_metadata(bag, bag_metadata(contents.files, contents.topics))
    return RepairReport(bag, files, contents)


def resume(bag_dir: str | os.PathLike, **writer_options) -> tuple[BagWriter, RepairReport]:
    """Repair the bag at ``bag_dir`` and open a :class:`BagWriter` that continues it in a
    new file (keyword arguments as for BagWriter); the repair's report comes with it."""
    report = repair(bag_dir)
    return BagWriter(bag_dir, continues=report.contents, **writer_options), report


def _rewrite(bag: Path, mcap: Path, scan: McapScan) -> tuple[int, int]:
    """Rewrite the unfinished ``mcap`` from its complete chunks; the chunks read and the
    bytes dropped."""
    tmp = bag / '.repair'
    if tmp.exists():
        shutil.rmtree(tmp)  # left over from an interrupted repair
    # The fresh file gets the damaged one's name (it is named after its directory).
    with BagWriter(tmp / mcap.stem, chunk_messages=2**31, flush_period=float('inf')) as writer:
        for channel, stamp, data in scan:
            if channel.topic not in writer.topics:
                _add_topic(writer, channel)
            writer.write(channel.topic, data, stamp)
        for channel in scan.channels.values():  # topics without messages
            if channel.topic not in writer.topics:
                _add_topic(writer, channel)
    os.replace(writer.mcap_path, mcap)
    shutil.rmtree(tmp)
    return scan.chunks, scan.size - scan.end


def _add_topic(writer: BagWriter, channel: Channel) -> None:
    record = _record(channel)
    writer.add_topic(channel.topic, channel.msgtype, record.offered_qos,
                     msgdef=channel.msgdef, type_hash=record.type_hash)


def _contents(mcap: Path, scan: McapScan) -> tuple[FileSpan, list[TopicRecord]]:
    """The span and topics (with counts) of one finished MCAP file, read message by
    message."""
    records: dict[str, TopicRecord] = {}
    start, end = 2**63 - 1, 0
    for channel, stamp, _ in scan:
        record = records.get(channel.topic)
        if record is None:
            record = records[channel.topic] = _record(channel)
        record.count += 1
        start, end = min(start, stamp), max(end, stamp)
    for channel in scan.channels.values():  # topics without messages
        if channel.topic not in records:
            records[channel.topic] = _record(channel)
    count = sum(r.count for r in records.values())
    return FileSpan(mcap.name, start, end, count), list(records.values())
