"""recorder: writes every message on the project's topics into a rosbag2 bag (MCAP).

Subscribes, raw (messages are never deserialized), to every topic whose name starts with
one of ``topics_prefixes``: the project's own topics (:data:`dlmpc_ros.ros.io.QOS`) from
the start, so that nothing is lost to discovery, and any other topic as the periodic
graph discovery finds it. ``/laser/state`` is subscribed last, once the publishers named
in ``wait_for_publishers`` are matched: ``laser_sim``'s ``wait_for_subscribers`` counts
its readers, so the others are matched before it runs.
A topic enters the bag with its first message, with its publishers' QoS profiles. On
SIGINT/SIGTERM the bag is closed and the message counts are logged; a recorder killed
harder loses at most ``flush_period`` seconds (``dlmpc-bag repair`` restores the rest).
With ``append`` a recorder started on an existing bag repairs it and continues it in a
new file (``NAME_1.mcap``, ...): the bringup restarts a killed recorder so, and the bag
reads as one, with the round trips of the restart missing.
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path

from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from dlmpc_ros import interfaces as itf
from dlmpc_ros.health import Findings, Health
from dlmpc_ros.recording.repair import resume
from dlmpc_ros.recording.writer import FLOAT64_MULTI_ARRAY, BagError, BagWriter, make_qos
from dlmpc_ros.ros import params
from dlmpc_ros.ros.diagnostics import DiagnosticsPublisher
from dlmpc_ros.ros.io import QOS, STREAM_QOS

DEFAULTS: dict[str, object] = {'output': '', 'append': False,
                               'topics_prefixes': ['/laser/', '/estimator/', '/controller/'],
                               'discovery_period': 1.0, 'flush_period': 0.5,
                               'wait_for_publishers': '', 'wait_timeout': 10.0}
DESCRIPTIONS = {
    'output': 'bag directory to create (must not exist unless append is set)',
    'append': 'if output is a bag already, repair it and continue it in a new file',
    'topics_prefixes': 'record every topic whose name starts with one of these',
    'discovery_period': 'look for new topics this often [s]',
    'flush_period': 'write the open chunk to disk at least this often [s]',
    'wait_for_publishers': 'comma-separated topics whose publishers must be matched before '
                           '/laser/state is subscribed (the bringup names its nodes\' topics)',
    'wait_timeout': 'longest wait for those publishers before subscribing anyway [s]',
}
READ_ONLY = frozenset(DEFAULTS)
#: Longest time a stopping recorder spends writing its backlog [s].
DRAIN_SECONDS = 10.0
#: Periods and waits the node can run (a timer of 1e300 s overflows).
RANGES = {'discovery_period': (0.01, 3600.0), 'flush_period': (0.01, 3600.0),
          'wait_timeout': (0.0, 3600.0)}


def offered_qos(profile: QoSProfile):
    """A publisher's QoS profile as the bag records it."""
    return make_qos(int(profile.history), profile.depth, int(profile.reliability),
                    int(profile.durability), profile.deadline.nanoseconds,
                    profile.lifespan.nanoseconds, int(profile.liveliness),
                    profile.liveliness_lease_duration.nanoseconds,
                    profile.avoid_ros_namespace_conventions)


class RecorderNode(Node):
    def __init__(self) -> None:
        super().__init__('recorder')
        values = params.declare(self, DEFAULTS, DESCRIPTIONS, READ_ONLY, RANGES)
        output = str(values['output'])
        self.prefixes = tuple(values['topics_prefixes'])
        problems = []
        if not output:
            problems.append('output must name the bag directory to create')
        elif Path(output).exists() and not values['append']:
            problems.append(f'output {output} exists already (a bag is never overwritten; '
                            'set append:=true to continue it)')
        if not self.prefixes or not all(p.startswith('/') for p in self.prefixes):
            problems.append(f'topics_prefixes must be topic name prefixes starting with /, '
                            f'got {list(self.prefixes)}')
        if problems:
            raise params.StartupError('; '.join(problems))
        verb = 'continue' if Path(output).exists() else 'create'
        try:
            if verb == 'continue':
                self.writer, report = resume(output, flush_period=values['flush_period'])
                self.get_logger().info(
                    f'continuing {output} in {self.writer.mcap_path.name} after '
                    f'{report.message_count} messages in {len(report.files)} file(s)'
                    f'{" (repaired)" if report.rewritten else ""}')
            else:
                self.writer = BagWriter(output, flush_period=values['flush_period'])
        except (BagError, OSError) as err:
            raise params.StartupError(f'cannot {verb} the bag: {err}') from None
        self.finished = False
        self.exit_code = 0
        self._warn = itf.RateLimitedLog(self.get_logger().warning, period=10.0)
        self._types: dict[str, str] = {}
        self._subscriptions_by_topic = {}
        self._in_bag: set[str] = set()
        known = [t for t in QOS if t.startswith(self.prefixes) and t != itf.TOPIC_STATE]
        for topic in known:
            self._subscribe(topic, FLOAT64_MULTI_ARRAY)
        # /laser/state last, once the named publishers are matched: laser_sim waits for
        # its readers, so nothing the others publish is lost to discovery.
        named = [t.strip() for t in str(values['wait_for_publishers']).split(',')]
        self._awaited = [t for t in named if t in self._subscriptions_by_topic]
        self._gate_deadline = time.monotonic() + values['wait_timeout']
        self._gate_timer = self.create_timer(0.05, self._open_gate)
        self._open_gate()
        self._discover()
        self.create_timer(values['discovery_period'], self._discover)
        self.create_timer(values['flush_period'], self.writer.flush)
        self._diagnostics = DiagnosticsPublisher(self, self._health)
        self.get_logger().info(f'recording topics under {", ".join(self.prefixes)} '
                               f'to {output}')

    def _health(self, findings: Findings, now: float) -> Health:
        counts = dict(self.writer.counts)
        findings.values.update(bag=str(self.writer.path), messages_written=sum(counts.values()),
                               **{f'{topic} messages': n for topic, n in counts.items()})
        if self.exit_code:
            findings.errors.append(f'cannot write {self.writer.path}')
        if self._gate_timer is not None:
            findings.values['waiting_for'] = ', '.join(self._awaited)
        return findings.health(f'{sum(counts.values())} messages of {len(counts)} topics '
                               'written')

    def _open_gate(self) -> None:
        """Subscribe /laser/state once every awaited topic has a matched publisher (or
        the wait timed out)."""
        if self._gate_timer is None:
            return
        missing = [t for t in self._awaited
                   if self._subscriptions_by_topic[t].get_publisher_count() == 0]
        if missing and time.monotonic() < self._gate_deadline:
            return
        if missing:
            self.get_logger().warning(f'no publisher matched on {missing}; recording anyway')
        self._gate_timer.cancel()
        self._gate_timer = None
        if itf.TOPIC_STATE.startswith(self.prefixes):
            self._subscribe(itf.TOPIC_STATE, FLOAT64_MULTI_ARRAY)

    def _discover(self) -> None:
        for topic, types in self.get_topic_names_and_types():
            if not topic.startswith(self.prefixes) or (
                    topic == itf.TOPIC_STATE and self._gate_timer is not None):
                continue
            if topic in self._types:
                if types != [self._types[topic]]:
                    self._warn(f'type:{topic}', f'{topic} has types {types}; recording only '
                               f'{self._types[topic]}')
                continue
            if len(types) != 1:
                self._warn(f'type:{topic}', f'not recording {topic}: it has types {types}')
                continue
            self._subscribe(topic, types[0])

    def _subscribe(self, topic: str, msgtype: str) -> None:
        try:
            package, kind, name = msgtype.split('/')
            msg_class = getattr(importlib.import_module(f'{package}.{kind}'), name)
        except (ValueError, ImportError, AttributeError):
            self._warn(f'type:{topic}', f'not recording {topic}: type {msgtype} is not '
                       'installed')
            return
        self._types[topic] = msgtype
        self._subscriptions_by_topic[topic] = self.create_subscription(
            msg_class, topic, self._callback(topic, msgtype), self._qos(topic), raw=True)

    def _qos(self, topic: str) -> QoSProfile:
        """io.py's profile; for other topics a keep-last-1000 one that matches every offer."""
        if topic in QOS:
            return QOS[topic]
        offers = self.get_publishers_info_by_topic(topic)
        reliable = all(i.qos_profile.reliability == ReliabilityPolicy.RELIABLE for i in offers)
        return QoSProfile(history=STREAM_QOS.history, depth=STREAM_QOS.depth,
                          durability=STREAM_QOS.durability,
                          reliability=ReliabilityPolicy.RELIABLE if reliable
                          else ReliabilityPolicy.BEST_EFFORT)

    def _callback(self, topic: str, msgtype: str):
        write = self.writer.write
        now = time.time_ns
        in_bag = self._in_bag

        def on_message(data: bytes) -> None:
            stamp = now()
            try:
                if topic not in in_bag:
                    self._add_to_bag(topic, msgtype)
                write(topic, data, stamp)
            except (OSError, BagError) as err:
                self._fail(err)

        return on_message

    def _add_to_bag(self, topic: str, msgtype: str) -> None:
        offers = [offered_qos(i.qos_profile) for i in self.get_publishers_info_by_topic(topic)]
        self.writer.add_topic(topic, msgtype, offers)
        self._in_bag.add(topic)
        self.get_logger().info(f'recording {topic} ({msgtype})')

    def _fail(self, err: Exception) -> None:
        if not self.finished:
            self.get_logger().fatal(f'cannot write {self.writer.path}: {err}')
            self.finished = True
            self.exit_code = 1

    def drain(self, executor) -> None:
        """Write what the subscriptions still hold (the bringup stops the recorder last, so
        its backlog is all that is left of the run)."""
        if not self.writer.closed:
            params.drain_until_quiet(executor, lambda: sum(self.writer.counts.values()),
                                     longest=DRAIN_SECONDS)

    def stop(self) -> None:
        """Close the bag (summary, footer, metadata.yaml) and log what was written."""
        if self.writer.closed:
            return
        try:
            self.writer.close()
        except OSError as err:
            self._fail(err)
            return
        counts = self.writer.counts
        listing = ', '.join(f'{topic} {n}' for topic, n in counts.items()) or 'no topics'
        self.get_logger().info(f'wrote {sum(counts.values())} messages to {self.writer.path}:'
                               f' {listing}')


def main(args: list[str] | None = None) -> None:
    sys.exit(params.run_node(RecorderNode, args, executor_factory=EventsExecutor))


if __name__ == '__main__':
    main()
