"""Load a rosbag2 bag into numpy arrays per topic, and check the round-trip index.

Only ``std_msgs/msg/Float64MultiArray`` topics (every topic of this project) are loaded;
each becomes a :class:`BagTopic` with one row per message. Messages of one length share
their CDR layout, so their values are cut out of the raw bytes in one numpy operation
(checked against rosbags' deserializer on one message of each length).
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
        try:
            fields, data = decode_float64_arrays(raws[topic])
        except ValueError as err:
            raise BagError(f'{topic} in {path}: {err}') from None
        result[topic] = BagTopic(topic, fields, np.array(stamps[topic], dtype=np.int64), data)
    return result


def decode_float64_arrays(raws: Sequence[bytes]) -> tuple[tuple[str, ...], np.ndarray]:
    """Field names and (n, width) values of CDR-serialized Float64MultiArray messages;
    ``width`` is the longest message's length, and shorter messages (the controller's
    status holds the predicted O only in the outer loop) are padded with NaN."""
    if not raws:
        return (), np.zeros((0, 0))
    store = jazzy_typestore()
    first = store.deserialize_cdr(raws[0], FLOAT64_MULTI_ARRAY)
    label = first.layout.dim[0].label if len(first.layout.dim) else ''
    fields = tuple(label.split(',')) if label else ()
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
    groups = [(np.flatnonzero(lengths == length),
               _cut_values(store, [raws[i] for i in np.flatnonzero(lengths == length)],
                           int(length)))
              for length in np.unique(lengths)]
    data = np.full((len(raws), max(values.shape[1] for _, values in groups)), np.nan)
    for rows, values in groups:
        data[rows, :values.shape[1]] = values
    return fields, data


def _cut_values(store, group: list[bytes], length: int) -> np.ndarray:
    """(k, width) values of k messages of equal byte length."""
    sample = store.deserialize_cdr(group[0], FLOAT64_MULTI_ARRAY)
    width = len(sample.data)
    head = length - 8 * width
    raw = np.frombuffer(b''.join(group), dtype=np.uint8).reshape(len(group), length)
    dtype = np.dtype('<f8' if group[0][1] == 1 else '>f8')  # CDR_LE / CDR_BE
    if head >= 4 and (raw[:, :head] == raw[0, :head]).all():
        values = np.ascontiguousarray(raw[:, head:]).view(dtype).astype(np.float64)
        if np.array_equal(values[0], np.asarray(sample.data, dtype=float), equal_nan=True):
            return values
    # Layouts differ within the group (or the shortcut does not apply): decode one by one.
    decoded = [store.deserialize_cdr(r, FLOAT64_MULTI_ARRAY).data for r in group]
    if any(len(d) != width for d in decoded):
        raise ValueError('messages of equal size hold different numbers of values')
    return np.array(decoded, dtype=np.float64).reshape(len(group), width)


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
