"""The bringup's own node: waits for the graph, shows status, records the run to CSV.

Each recorded row is a ``/laser/state`` message joined by round trip with the K that the
simulator used for it (``/laser/sim_truth``); without a simulator (a hardware driver),
K is NaN. Each control decision (``/controller/status``) goes to a second CSV
(:func:`decisions_path`) with the estimator's latency for the same round trip.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.graph import STARTUP_ERROR, NodeGraph
from dlmpc_ros.ros.io import QOS
from dlmpc_ros.ros.params import process_age
from dlmpc_ros.ros.teardown import TEARDOWN_GRACE, exit_after
from dlmpc_ros.recording.run_csv import DECISION_FIELDS, decisions_path, write_header, write_row

#: States wait at most this many rows for their K before they are written without it.
MAX_PENDING = 2000
#: Decisions wait at most this many for their estimate (it travels on another topic).
MAX_PENDING_DECISIONS = 16
#: Longest wait at the end of a lockstep run for the decisions still on their way [s] (a
#: decision's status and the laser's next states travel on separate topics).
DECISION_GRACE = 2.0


class MonitorNode(Node):
    """Joins state and true K by round trip and hands each row to ``on_row`` in order."""

    def __init__(self, on_row: Callable[[list[float], float], None],
                 on_decision: Callable[[list[float]], None] | None = None) -> None:
        super().__init__('bringup_monitor')
        self._on_decision = on_decision
        self._estimate_latency: dict[int, float] = {}
        self._latest_estimate = -1
        self._decisions: deque[list[float]] = deque()
        self.decisions = 0
        self.latest_decision = -1  # round trip of the latest status heard
        self.state: list[float] | None = None
        self.k = math.nan
        self.k_seen = False
        self.count = 0
        self._on_row = on_row
        self._pending: deque[list[float]] = deque()
        self._truth: dict[int, float] = {}
        self._latest_truth = -1
        for topic, handler in ((itf.TOPIC_STATE, self._on_state),
                               (itf.TOPIC_SIM_TRUTH, self._on_truth),
                               (itf.TOPIC_BIREFRINGENCE, self._on_k)):
            self.create_subscription(Float64MultiArray, topic, handler, QOS[topic])
        if on_decision is not None:
            for topic, handler in ((itf.TOPIC_CONTROLLER_STATUS, self._on_status),
                                   (itf.TOPIC_ESTIMATE, self._on_estimate)):
                self.create_subscription(Float64MultiArray, topic, handler, QOS[topic])

    def _on_estimate(self, msg: Float64MultiArray) -> None:
        data = msg.data
        if len(data) >= len(itf.ESTIMATE_FIELDS) and math.isfinite(data[0]):
            self._estimate_latency[int(data[0])] = data[2]
            self._latest_estimate = max(self._latest_estimate, int(data[0]))
            while len(self._estimate_latency) > 256:
                self._estimate_latency.pop(next(iter(self._estimate_latency)))
            self.flush_decisions()

    def _on_status(self, msg: Float64MultiArray) -> None:
        data = list(msg.data[:len(itf.CONTROLLER_STATUS_FIELDS)])
        if len(data) == len(itf.CONTROLLER_STATUS_FIELDS) and math.isfinite(data[0]):
            self._decisions.append(data)
            self.latest_decision = max(self.latest_decision, int(data[0]))
            self.flush_decisions()

    def flush_decisions(self, everything: bool = False) -> None:
        """Hand on the decisions whose estimate has come, or will not come (no estimator,
        a later estimate seen, or too many waiting), in order."""
        while self._decisions:
            round_trip = int(self._decisions[0][0])
            if not (round_trip in self._estimate_latency or everything
                    or self._latest_estimate < 0 or self._latest_estimate > round_trip
                    or len(self._decisions) > MAX_PENDING_DECISIONS):
                break
            data = self._decisions.popleft()
            self.decisions += 1
            self._on_decision([*data, self._estimate_latency.pop(round_trip, math.nan)])

    def _on_state(self, msg: Float64MultiArray) -> None:
        if itf.vector_fault(msg.data, itf.STATE_FIELDS, 1e300) is None:
            self._pending.append(list(msg.data))
            self.count += 1
            self.flush()

    def _on_truth(self, msg: Float64MultiArray) -> None:
        if itf.vector_fault(msg.data, itf.SIM_TRUTH_FIELDS, 1e300) is None:
            round_trip = int(msg.data[0])
            self._truth[round_trip] = msg.data[1]
            self._latest_truth = max(self._latest_truth, round_trip)
            self.flush()

    def _on_k(self, msg: Float64MultiArray) -> None:
        self.k_seen = True

    def flush(self, everything: bool = False) -> None:
        """Hand on the rows whose K is known, or will never come."""
        while self._pending:
            round_trip = int(self._pending[0][0])
            known = round_trip in self._truth
            if not (known or everything or round_trip < self._latest_truth
                    or len(self._pending) > MAX_PENDING):
                break
            self.state = self._pending.popleft()
            self.k = self._truth.pop(round_trip, math.nan)
            self._on_row(self.state, self.k)
        if len(self._truth) > MAX_PENDING:  # truths of states that never came
            oldest = int(self._pending[0][0]) if self._pending else self._latest_truth
            self._truth = {r: k for r, k in self._truth.items() if r >= oldest}


def status_line(state: list[float], k: float, rate: float) -> str:
    """One-line live status of the run."""
    k_text = f'{k:+.4f}' if math.isfinite(k) else '   n/a'
    return (f'round trip {int(state[0]):>9d}  O {state[3]:.4f}  E {state[1]:.3f}  '
            f'M {state[2]:7.2f}  K {k_text}  {rate:6.0f} RT/s')


def run_monitor(args: argparse.Namespace, graph: NodeGraph, requested: threading.Event,
                finish: Callable[[int], int]) -> int:
    """Spin the monitor until the run ends or ``requested`` is set (SIGINT, SIGTERM), then
    ``finish(code)`` (stop the graph; returns the bringup's exit code) before the monitor's
    own node goes, so that a middleware teardown that hangs (:mod:`dlmpc_ros.ros.teardown`)
    cannot leave the graph running; returns the bringup's exit code."""
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    files = []
    writer = decision_writer = None
    limit = args.round_trips
    if args.csv is not None:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        files.append(open(args.csv, 'w', newline=''))
        writer = csv.writer(files[-1])
        write_header(writer)
        files.append(open(decisions_path(args.csv), 'w', newline=''))
        decision_writer = csv.writer(files[-1])
        decision_writer.writerow(DECISION_FIELDS)

    def on_row(state: list[float], k: float) -> None:
        if writer is not None and (limit == 0 or state[0] <= limit):
            write_row(writer, [*state, k])

    def on_decision(row: list[float]) -> None:
        if limit == 0 or row[0] <= limit:
            write_row(decision_writer, row)

    node = MonitorNode(on_row, on_decision if decision_writer is not None else None)
    executor = EventsExecutor()
    executor.add_node(node)
    code = 1  # if the spin raises
    try:
        code = _spin(args, graph, requested, node, executor)
    finally:
        node.flush(everything=True)
        node.flush_decisions(everything=True)
        if sys.stdout.isatty():
            print()
        if node.state is not None:
            print('bringup: last ' + status_line(node.state, node.k, 0.0).rsplit('  ', 1)[0])
        for handle in files:
            handle.close()
        code = finish(code)
        with exit_after(TEARDOWN_GRACE, code):
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown()
    return code


def _spin(args: argparse.Namespace, graph: NodeGraph, requested: threading.Event,
          node: MonitorNode, executor: EventsExecutor) -> int:
    """Wait for the graph to connect, then show status until the run ends; returns the
    exit code so far (0: ran to the end or stopped on request)."""
    limit = args.round_trips
    need_k = 'drift_injector' in args.nodes
    tty = sys.stdout.isatty()
    start = time.monotonic()
    while node.state is None or (need_k and not node.k_seen):
        executor.spin_once(timeout_sec=0.1)
        if requested.is_set():
            return 0
        if graph.died() or time.monotonic() - start > args.connect_timeout:
            print('bringup: the graph did not connect', file=sys.stderr)
            return _report_dead(graph) or 2
    print(f'bringup: graph connected {process_age():.1f} s after the bringup started',
          flush=True)
    last_print, last_count, last_time = 0.0, node.count, time.monotonic()
    while limit == 0 or node.state[0] < limit:
        executor.spin_once(timeout_sec=0.05)
        if requested.is_set():
            print('\nbringup: interrupted, stopping the graph', flush=True)
            break
        if graph.died():
            return _report_dead(graph)
        now = time.monotonic()
        if now - last_print >= (0.25 if tty else 2.0):
            rate = (node.count - last_count) / max(now - last_time, 1e-9)
            last_count, last_time, last_print = node.count, now, now
            line = status_line(node.state, node.k, rate)
            print('\r' + line if tty else line, end='' if tty else '\n', flush=True)
    if args.lockstep and args.controller != 'none' and args.csv is not None:
        # (the monitor hears decisions for the CSV only)
        last = limit - limit % args.period  # the last decision's round trip
        deadline = time.monotonic() + DECISION_GRACE
        while node.latest_decision < last and time.monotonic() < deadline \
                and not requested.is_set():
            executor.spin_once(timeout_sec=0.05)
    return 0


def _report_dead(graph: NodeGraph) -> int:
    """Say which nodes died and how; 2 when one could not start with its settings (as a
    node itself exits), 1 for any other death, 0 if none died."""
    dead = graph.died()
    for node in dead:
        print(f'bringup: node {node.name} exited with code {node.process.returncode}; '
              f'last lines of {node.log_path}:\n{node.log_tail()}', file=sys.stderr)
    if any(node.process.returncode == STARTUP_ERROR for node in dead):
        return 2
    return 1 if dead else 0
