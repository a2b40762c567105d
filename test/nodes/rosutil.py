"""Helpers for node tests: node processes and an in-test rclpy probe node.

The probe spins in the test's own thread (no spin thread left behind) on its own
context, in the domain that the ``ros_env`` fixture chose.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from std_msgs.msg import Float64MultiArray

from dlmpc_ros.ros.io import QOS, vector_message


class NodeProcess:
    """A node run as ``python -m module --ros-args ...``, output captured to a file."""

    def __init__(self, module: str, env: dict[str, str], log: Path, *ros_args: str) -> None:
        self.log = log
        self._handle = open(log, 'wb')
        self.proc = subprocess.Popen([sys.executable, '-m', module, '--ros-args', *ros_args],
                                     env=env, stdout=self._handle, stderr=subprocess.STDOUT)

    def output(self) -> str:
        return self.log.read_text(errors='replace')

    def stop(self, timeout: float = 15.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._handle.close()
        return self.proc.returncode


class Probe:
    """A test-side node that records topics and publishes vectors."""

    def __init__(self, name: str = 'probe') -> None:
        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict[str, list[Float64MultiArray]] = {}
        self.publishers = {}

    def listen(self, topic: str) -> list[Float64MultiArray]:
        box = self.received.setdefault(topic, [])
        self.node.create_subscription(Float64MultiArray, topic, box.append, QOS[topic])
        return box

    def publisher(self, topic: str):
        if topic not in self.publishers:
            self.publishers[topic] = self.node.create_publisher(Float64MultiArray, topic,
                                                                QOS[topic])
        return self.publishers[topic]

    def publish(self, topic: str, data: list[float], fields=None) -> None:
        msg = Float64MultiArray(data=[float(x) for x in data]) if fields is None \
            else vector_message(fields, data)
        self.publisher(topic).publish(msg)

    def spin_until(self, condition: Callable[[], bool], timeout: float,
                   what: str = 'condition') -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise TimeoutError(f'timed out after {timeout} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, client, request, timeout: float):
        """Call a service and wait for its answer, asking again after a lost one: Fast DDS
        drops a response sent before the server has matched the client's response reader,
        which ``service_is_ready`` does not wait for (only for idempotent requests)."""
        deadline = time.monotonic() + timeout
        while True:
            future = client.call_async(request)
            try:
                self.spin_until(future.done, min(5.0, deadline - time.monotonic()),
                                f'an answer of {client.srv_name}')
                return future.result()
            except TimeoutError:
                client.remove_pending_request(future)
                if time.monotonic() >= deadline - 0.1:
                    raise

    def wait_matched(self, topic: str, timeout: float = 30.0) -> None:
        pub = self.publisher(topic)
        self.spin_until(lambda: pub.get_subscription_count() > 0, timeout, f'a reader of {topic}')

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
