"""Start, watch and stop node processes (plain subprocess; no ROS launch, no rclpy)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class NodeProcess:
    """One node to run as ``python -m module --ros-args ...`` with its log file."""

    name: str
    module: str
    params_file: Path | None = None
    overrides: dict[str, object] = field(default_factory=dict)
    process: subprocess.Popen | None = None
    log_path: Path | None = None
    stopping: bool = False

    def command(self) -> list[str]:
        cmd = [sys.executable, '-m', self.module, '--ros-args']
        if self.params_file is not None:
            cmd += ['--params-file', str(self.params_file)]
        for key, value in self.overrides.items():
            cmd += ['-p', f'{key}:={ros_value(value)}']
        return cmd

    def log_tail(self, lines: int = 15) -> str:
        if self.log_path is None or not self.log_path.exists():
            return ''
        return '\n'.join(self.log_path.read_text(errors='replace').splitlines()[-lines:])


def ros_value(value: object) -> str:
    """Format a Python value for ``-p name:=value`` (YAML) without losing its type."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(ros_value(v) for v in value) + ']'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    return str(value)


class NodeGraph:
    """A set of node processes, each in its own session so that only the bringup sees
    the terminal's Ctrl-C and can stop them in order."""

    def __init__(self, nodes: list[NodeProcess], env: dict[str, str], log_dir: Path) -> None:
        self.nodes = nodes
        self.env = env
        self.log_dir = log_dir

    def start(self) -> None:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        for node in self.nodes:
            node.log_path = self.log_dir / f'{node.name}.log'
            with open(node.log_path, 'wb') as log:
                node.process = subprocess.Popen(node.command(), env=self.env, stdout=log,
                                                stderr=subprocess.STDOUT,
                                                stdin=subprocess.DEVNULL,
                                                start_new_session=True)

    def died(self) -> list[NodeProcess]:
        """Nodes that exited without being asked to."""
        return [n for n in self.nodes
                if n.process is not None and not n.stopping and n.process.poll() is not None]

    def stop(self, timeout: float = 10.0) -> dict[str, int]:
        """SIGINT every node, wait up to ``timeout`` s, then SIGTERM, then SIGKILL.

        Returns each node's exit code (negative: killed by that signal).
        """
        running = [n for n in self.nodes if n.process is not None]
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 3.0),
                          (signal.SIGKILL, 3.0)):
            alive = [n for n in running if n.process.poll() is None]
            if not alive:
                break
            for node in alive:
                node.stopping = True
                try:
                    os.kill(node.process.pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline and any(n.process.poll() is None for n in alive):
                time.sleep(0.05)
        return {n.name: n.process.wait() for n in running}
