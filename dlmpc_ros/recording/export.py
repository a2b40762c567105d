"""A recorded bag as the bringup's CSV files (no rclpy), so that a bag and a live run go
through the same metrics and plots.

``run.csv`` gets one row per ``/laser/state`` message with the K of ``/laser/sim_truth``
for the same round trip (NaN when the bag has none: a hardware laser); ``run.controller.csv``
gets one row per ``/controller/status`` message with the estimator's latency of
``/estimator/birefringence`` for the same round trip (NaN without one).
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dlmpc_ros import interfaces as itf
from dlmpc_ros.recording.reader import BagTopic, read_bag, read_metadata
from dlmpc_ros.recording.writer import BagError
from dlmpc_ros.recording.run_csv import DECISION_FIELDS, decisions_path, write_header, write_row


@dataclass(frozen=True)
class ExportReport:
    """What :func:`bag_to_csv` wrote."""

    run_csv: Path
    decisions_csv: Path
    #: /laser/state rows, and how many of them have the true K.
    rows: int
    rows_with_k: int
    #: /controller/status rows, and how many have the estimator's latency.
    decisions: int
    decisions_with_estimate: int
    #: Messages left out because they did not fit their topic, per topic (if any).
    skipped: dict[str, int]

    def skipped_text(self) -> str:
        """``'; skipped N messages that do not fit (topic N, ...)'`` or ``''``."""
        if not self.skipped:
            return ''
        listing = ', '.join(f'{topic} {n}' for topic, n in self.skipped.items())
        return f'; skipped {sum(self.skipped.values())} messages that do not fit ({listing})'


def _by_round_trip(topic: BagTopic | None, column: int) -> dict[int, float]:
    if topic is None or not len(topic):
        return {}
    return dict(zip(topic.data[:, 0].astype(np.int64).tolist(), topic.data[:, column].tolist()))


def _checked(topic: BagTopic, fields: tuple[str, ...], bag: Path) -> BagTopic:
    """A topic whose messages carry at least ``fields`` (named as expected if labelled)."""
    if topic.fields and tuple(topic.fields[:len(fields)]) != fields:
        raise BagError(f'{topic.name} in {bag} has fields {topic.fields}, expected '
                       f'{fields}')
    if len(topic) and topic.data.shape[1] < len(fields):
        raise BagError(f'{topic.name} in {bag} has {topic.data.shape[1]} values per message, '
                       f'expected at least {len(fields)}')
    return topic


def bag_to_csv(bag: str | os.PathLike, run_csv: str | os.PathLike) -> ExportReport:
    """Write ``run_csv`` and its decisions CSV (:func:`decisions_path`) from a bag.

    Messages that do not fit their topic are left out and counted in the report. Raises
    :class:`BagError` if the bag has no ``/laser/state`` or its topics have the wrong
    layout."""
    bag, run_csv = Path(bag), Path(run_csv)
    names = {t['topic_metadata']['name'] for t in read_metadata(bag)['topics_with_message_count']}
    if itf.TOPIC_STATE not in names:
        raise BagError(f'{bag} has no {itf.TOPIC_STATE}; record the laser state to evaluate it')
    optional = (itf.TOPIC_SIM_TRUTH, itf.TOPIC_CONTROLLER_STATUS, itf.TOPIC_ESTIMATE)
    topics = read_bag(bag, [itf.TOPIC_STATE, *(t for t in optional if t in names)])
    state = _checked(topics[itf.TOPIC_STATE], itf.STATE_FIELDS, bag)
    expected = {itf.TOPIC_SIM_TRUTH: itf.SIM_TRUTH_FIELDS, itf.TOPIC_ESTIMATE: itf.ESTIMATE_FIELDS,
                itf.TOPIC_CONTROLLER_STATUS: itf.CONTROLLER_STATUS_FIELDS}
    for name, fields in expected.items():
        if name in topics:
            _checked(topics[name], fields, bag)
    k_of = _by_round_trip(topics.get(itf.TOPIC_SIM_TRUTH), 1)
    latency_of = _by_round_trip(topics.get(itf.TOPIC_ESTIMATE), 2)
    status = topics.get(itf.TOPIC_CONTROLLER_STATUS)
    n_status = len(itf.CONTROLLER_STATUS_FIELDS)
    run_csv.parent.mkdir(parents=True, exist_ok=True)
    rows_with_k = decisions_with_estimate = 0
    with open(run_csv, 'w', newline='') as handle:
        writer = csv.writer(handle)
        write_header(writer)
        for row in state.data[:, :len(itf.STATE_FIELDS)].tolist():
            k = k_of.get(int(row[0]), math.nan)
            rows_with_k += k == k
            write_row(writer, [*row, k])
    decisions = 0
    with open(decisions_path(run_csv), 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(DECISION_FIELDS)
        if status is not None:
            for row in status.data[:, :n_status].tolist():
                latency = latency_of.get(int(row[0]), math.nan)
                decisions_with_estimate += latency == latency
                write_row(writer, [*row, latency])
                decisions += 1
    return ExportReport(run_csv=run_csv, decisions_csv=decisions_path(run_csv),
                        rows=len(state), rows_with_k=rows_with_k, decisions=decisions,
                        decisions_with_estimate=decisions_with_estimate,
                        skipped={t: v.skipped for t, v in topics.items() if v.skipped})
