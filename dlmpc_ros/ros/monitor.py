"""The bringup's own node: waits for the graph, shows status, records the run to CSV."""

from __future__ import annotations

import argparse
import csv
import math
import sys
import time

import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64MultiArray

from dlmpc_ros import interfaces as itf
from dlmpc_ros.graph import NodeGraph
from dlmpc_ros.ros.io import QOS
from dlmpc_ros.ros.params import stop_on_signals


class MonitorNode(Node):
    """Keeps the latest state and K; hands every state row to ``on_row``."""

    def __init__(self, on_row) -> None:
        super().__init__('bringup_monitor')
        self.state: list[float] | None = None
        self.k = math.nan
        self.k_seen = False
        self.count = 0
        self._on_row = on_row
        self.create_subscription(Float64MultiArray, itf.TOPIC_STATE, self._on_state,
                                 QOS[itf.TOPIC_STATE])
        self.create_subscription(Float64MultiArray, itf.TOPIC_BIREFRINGENCE, self._on_k,
                                 QOS[itf.TOPIC_BIREFRINGENCE])

    def _on_state(self, msg: Float64MultiArray) -> None:
        if itf.vector_fault(msg.data, itf.STATE_FIELDS, 1e300) is None:
            self.state = list(msg.data)
            self.count += 1
            self._on_row(self.state, self.k)

    def _on_k(self, msg: Float64MultiArray) -> None:
        if itf.vector_fault(msg.data, itf.BIREFRINGENCE_FIELDS, 1e300) is None:
            self.k = msg.data[0]
            self.k_seen = True


def run_monitor(args: argparse.Namespace, graph: NodeGraph) -> int:
    """Spin the monitor until the run ends; returns the bringup's exit code so far."""
    from dlmpc_ros.bringup import status_line, write_header

    requested = stop_on_signals()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    csv_file = None
    writer = None
    limit = args.round_trips
    if args.csv is not None:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        csv_file = open(args.csv, 'w', newline='')
        writer = csv.writer(csv_file)
        write_header(writer)

    def on_row(state: list[float], k: float) -> None:
        if writer is not None and (limit == 0 or state[0] <= limit):
            writer.writerow([*(repr(x) for x in state), repr(k)])

    node = MonitorNode(on_row)
    executor = EventsExecutor()
    executor.add_node(node)
    need_k = 'drift_injector' in args.nodes
    tty = sys.stdout.isatty()
    code = 0
    try:
        start = time.monotonic()
        while node.state is None or (need_k and not node.k_seen):
            executor.spin_once(timeout_sec=0.1)
            if requested.is_set():
                return 0
            if graph.died() or time.monotonic() - start > args.connect_timeout:
                print('bringup: the graph did not connect', file=sys.stderr)
                return _report_dead(graph) or 2
        print(f'bringup: graph connected after {time.monotonic() - start:.1f} s', flush=True)
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
    finally:
        if tty:
            print()
        if node.state is not None:
            print('bringup: last ' + status_line(node.state, node.k, 0.0).rsplit('  ', 1)[0])
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        if csv_file is not None:
            csv_file.close()
    return code


def _report_dead(graph: NodeGraph) -> int:
    for node in graph.died():
        print(f'bringup: node {node.name} exited with code {node.process.returncode}; '
              f'last lines of {node.log_path}:\n{node.log_tail()}', file=sys.stderr)
    return 1 if graph.died() else 0
