"""Helpers for the recording tests: serialized messages and what an open bag has flushed."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording.repair import McapScan, find_mcaps
from dlmpc_ros.recording.writer import FLOAT64_MULTI_ARRAY, jazzy_typestore


def serialize(fields, values) -> bytes:
    """A labelled Float64MultiArray serialized by rosbags' Jazzy typestore (no rclpy)."""
    store = jazzy_typestore()
    types = store.types
    layout = types['std_msgs/msg/MultiArrayLayout'](
        dim=[types['std_msgs/msg/MultiArrayDimension'](label=','.join(fields),
                                                       size=len(fields), stride=len(fields))],
        data_offset=0)
    msg = types[FLOAT64_MULTI_ARRAY](layout=layout, data=np.asarray(values, dtype=np.float64))
    return bytes(store.serialize_cdr(msg, FLOAT64_MULTI_ARRAY))


def state(round_trip: int) -> list[float]:
    return [float(round_trip), 4.0, 30.0, 4.0 / 30.0, 16.0, 3.0, -0.39, -0.25, 0.52, -0.14]


def flushed_counts(bag: Path) -> Counter:
    """Messages per topic that a (possibly still open) bag has written to disk."""
    try:
        return Counter(channel.topic for mcap in find_mcaps(bag)
                       for channel, _, _ in McapScan(mcap))
    except (OSError, ValueError):
        return Counter()


def write_run(writer, round_trips, start_ns: int = 1_700_000_000_000_000_000) -> None:
    """Write laser_sim's three messages per round trip, 1 us apart."""
    for r in round_trips:
        stamp = start_ns + 3000 * r
        writer.write(itf.TOPIC_SIM_TRUTH, serialize(itf.SIM_TRUTH_FIELDS, [r, 0.01 * r]), stamp)
        writer.write(itf.TOPIC_STATE, serialize(itf.STATE_FIELDS, state(r)), stamp + 1000)
        writer.write(itf.TOPIC_OBJECTIVE, serialize(itf.OBJECTIVE_FIELDS, [4.0 / 30.0]),
                     stamp + 2000)
