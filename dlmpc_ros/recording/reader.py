"""Load a rosbag2 bag into numpy arrays per topic, and check the round-trip index.

Only ``std_msgs/msg/Float64MultiArray`` topics (every topic of this project) are loaded;
each becomes a :class:`BagTopic` with one row per message. Messages of one length share
their CDR layout, so their values are cut out of the raw bytes in one numpy operation
(checked against rosbags' deserializer on one message of each length). A message that
does not fit its topic (it does not decode as a Float64MultiArray, or its layout label is
not the topic's) is skipped and counted in :attr:`BagTopic.skipped`; the rest is kept.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from rosbags.rosbag2 import Reader, ReaderError

from dlmpc_ros.recording.writer import (
    FLOAT64_MULTI_ARRAY,
    METADATA_FILE,
    BagError,
    jazzy_typestore,
)


@dataclass(frozen=True)
class BagTopic:
    """All messages of one Float64MultiArray topic, in receive order."""

    name: str
    #: Field names from the layout's dimension label (empty if the messages have none).
    fields: tuple[str, ...]
    #: (n,) int64 receive times [ns since the epoch].
    timestamps_ns: np.ndarray
    #: (n, width) float64 message values; width is the longest message's, shorter ones
    #: are padded with NaN.
    data: np.ndarray
    #: Messages left out because they do not fit the topic (foreign or malformed).
    skipped: int = 0

    def __len__(self) -> int:
        return len(self.timestamps_ns)

    def column(self, name: str) -> np.ndarray:
        """(n,) values of one field."""
        if name not in self.fields:
            raise KeyError(f'{self.name} has no field {name!r} (fields: {self.fields})')
        return self.data[:, self.fields.index(name)]


def read_metadata(path: str | os.PathLike) -> dict:
    """The ``rosbag2_bagfile_information`` of a bag's ``metadata.yaml``."""
    path = Path(path)
    file = path / METADATA_FILE
    if not file.is_file():
        hint = (f' (was its recorder killed? run: dlmpc-bag repair {path})'
                if any(path.glob('*.mcap')) else '')
        raise BagError(f'{path} has no {METADATA_FILE}{hint}')
    try:
        return yaml.safe_load(file.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
    except (yaml.YAMLError, KeyError, TypeError) as err:
        raise BagError(f'{file} is not rosbag2 metadata: {err}') from None


def read_bag(path: str | os.PathLike, topics: Sequence[str] | None = None) -> dict[str, BagTopic]:
    """Load the Float64MultiArray topics of a bag.

    Parameters
    ----------
    path
        Bag directory (with ``metadata.yaml``).
    topics
        Topics to load; all Float64MultiArray topics when None. Asking for a topic that
        the bag lacks, or that has another type, raises :class:`BagError`.
    """
    path = Path(path)
    read_metadata(path)  # a clear message for a bag without one
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError) as err:
        raise BagError(f'cannot read bag {path}: {err}; if its recorder was killed, run: '
                       f'dlmpc-bag repair {path}') from None
    try:
        types = {c.topic: c.msgtype for c in reader.connections}
        wanted = [t for t, m in types.items() if m == FLOAT64_MULTI_ARRAY] \
            if topics is None else list(topics)
        for topic in wanted:
            if topic not in types:
                raise BagError(f'bag {path} has no topic {topic} (it has {sorted(types)})')
            if types[topic] != FLOAT64_MULTI_ARRAY:
                raise BagError(f'{topic} in {path} is {types[topic]}, not '
                               f'{FLOAT64_MULTI_ARRAY}')
        connections = [c for c in reader.connections if c.topic in wanted]
        stamps: dict[str, list[int]] = {t: [] for t in wanted}
        raws: dict[str, list[bytes]] = {t: [] for t in wanted}
        try:
            for connection, stamp, raw in reader.messages(connections=connections):
                stamps[connection.topic].append(stamp)
                raws[connection.topic].append(raw)
        except ReaderError as err:
            raise BagError(f'bag {path} is damaged: {err}; try: dlmpc-bag repair {path}') \
                from None
    finally:
        reader.close()
    result = {}
    for topic in wanted:
        fields, data, keep = decode_float64_arrays(raws[topic])
        stamp = np.array(stamps[topic], dtype=np.int64)[keep]
        result[topic] = BagTopic(topic, fields, stamp, data, len(raws[topic]) - int(keep.sum()))
    return result


def decode_float64_arrays(raws: Sequence[bytes]
                          ) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Field names, (k, width) values and the (n,) mask of the kept messages of
    CDR-serialized Float64MultiArray messages.

    ``width`` is the longest kept message's length, and shorter messages (the
    controller's status holds the predicted O only in the outer loop) are padded with
    NaN. The topic's layout is that of its most common label: a message whose fields
    extend it or are a part of it is kept (the fields are the longest such label's); one
    with other fields, or one that does not decode, is not."""
    keep = np.zeros(len(raws), bool)
    if not raws:
        return (), np.zeros((0, 0)), keep
    store = jazzy_typestore()
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
    groups = []  # (message indices, label of each, values (k, width) or None per message)
    for length in np.unique(lengths):
        rows = np.flatnonzero(lengths == length)
        groups.append((rows, *_cut_values(store, [raws[i] for i in rows], int(length))))
    labels: dict[str, int] = {}
    for _, group_labels, _ in groups:
        for label in group_labels:
            if label is not None:
                labels[label] = labels.get(label, 0) + 1
    if not labels:
        return (), np.zeros((0, 0)), keep
    base = _fields(max(labels, key=labels.get))
    fits = {label for label in labels if _compatible(_fields(label), base)}
    fields = max((_fields(label) for label in fits), key=len)
    width = max(len(v) for _, group_labels, values in groups
                for g, v in zip(group_labels, values) if g in fits)
    data = np.full((len(raws), width), np.nan)
    for rows, group_labels, values in groups:
        for row, g, v in zip(rows, group_labels, values):
            if g in fits:
                keep[row] = True
                data[row, :len(v)] = v
    return fields, data[keep], keep


def _fields(label: str) -> tuple[str, ...]:
    return tuple(label.split(',')) if label else ()


def _compatible(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    """Whether one field list starts with the other (unlabelled messages fit any)."""
    n = min(len(a), len(b))
    return a[:n] == b[:n]


def _cut_values(store, group: list[bytes], length: int
                ) -> tuple[list[str | None], list[np.ndarray | None]]:
    """Labels and values of k messages of equal byte length (None for one that does not
    decode as a Float64MultiArray)."""
    try:
        sample = store.deserialize_cdr(group[0], FLOAT64_MULTI_ARRAY)
    except Exception:  # noqa: BLE001 (foreign bytes): decode one by one below
        sample = None
    if sample is not None:
        width = len(sample.data)
        head = length - 8 * width
        raw = np.frombuffer(b''.join(group), dtype=np.uint8).reshape(len(group), length)
        dtype = np.dtype('<f8' if group[0][1] == 1 else '>f8')  # CDR_LE / CDR_BE
        if head >= 4 and (raw[:, :head] == raw[0, :head]).all():
            values = np.ascontiguousarray(raw[:, head:]).view(dtype).astype(np.float64)
            if np.array_equal(values[0], np.asarray(sample.data, dtype=float),
                              equal_nan=True):
                return [_label(sample)] * len(group), list(values)
    # Layouts differ within the group (or the shortcut does not apply): one by one.
    labels, out = [], []
    for raw_message in group:
        try:
            message = store.deserialize_cdr(raw_message, FLOAT64_MULTI_ARRAY)
            values = np.asarray(message.data, dtype=np.float64)
        except Exception:  # noqa: BLE001 (foreign bytes): skipped and counted
            labels.append(None)
            out.append(None)
            continue
        labels.append(_label(message))
        out.append(values)
    return labels, out


def _label(message) -> str:
    return message.layout.dim[0].label if len(message.layout.dim) else ''


@dataclass(frozen=True)
class RoundTripCheck:
    """How complete and ordered a sequence of round-trip indices is."""

    count: int
    #: Smallest and largest round trip (None without messages).
    first: int | None
    last: int | None
    #: Messages whose round trip was already seen.
    duplicates: int
    #: Messages whose round trip is smaller than the one before.
    out_of_order: int
    #: Missing round trips between first and last, as inclusive (start, end) ranges.
    gaps: tuple[tuple[int, int], ...]

    @property
    def missing(self) -> int:
        return sum(end - start + 1 for start, end in self.gaps)

    @property
    def contiguous(self) -> bool:
        """Every round trip from first to last exactly once, in order."""
        return self.count > 0 and not (self.duplicates or self.out_of_order or self.gaps)


def check_round_trips(round_trips: Iterable[float] | np.ndarray) -> RoundTripCheck:
    """Count gaps, duplicates and reorderings in a sequence of round-trip indices."""
    rt = np.asarray(round_trips, dtype=np.float64).astype(np.int64)
    if rt.size == 0:
        return RoundTripCheck(0, None, None, 0, 0, ())
    unique = np.unique(rt)
    steps = np.diff(unique)
    gaps = tuple((int(unique[i]) + 1, int(unique[i + 1]) - 1)
                 for i in np.flatnonzero(steps > 1))
    return RoundTripCheck(int(rt.size), int(unique[0]), int(unique[-1]),
                          int(rt.size - unique.size), int((np.diff(rt) < 0).sum()), gaps)
