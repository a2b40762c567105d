"""Start, watch, restart and stop node processes (plain subprocess; no ROS launch, no rclpy).

Each node's current process id is written to ``<log_dir>/<name>.pid`` while it runs (and
rewritten when the node is restarted), so that tools and tests can find a node without
searching the process table; the files are removed when the graph stops.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

#: Exit code of a node that cannot start with its settings: restarting it would not help.
STARTUP_ERROR = 2


@dataclass
class NodeProcess:
    """One node to run as ``python -m module --ros-args ...`` with its log file.

    ``respawn``: restart the node when it exits without being asked to (see
    :meth:`NodeGraph.respawn_exited`); ``restarts`` holds the monotonic times [s] of its
    recent restarts, ``restart_count`` counts all of them.
    """

    name: str
    module: str
    params_file: Path | None = None
    overrides: dict[str, object] = field(default_factory=dict)
    process: subprocess.Popen | None = None
    log_path: Path | None = None
    stopping: bool = False
    respawn: bool = False
    stop_last: bool = False
    restarts: deque[float] = field(default_factory=deque)
    restart_count: int = 0

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


def exit_text(code: int) -> str:
    """``code 1`` or ``signal SIGKILL`` for a Popen return code."""
    if code < 0:
        try:
            return f'signal {signal.Signals(-code).name}'
        except ValueError:
            return f'signal {-code}'
    return f'code {code}'


class NodeGraph:
    """A set of node processes, each in its own session so that only the bringup sees
    the terminal's Ctrl-C and can stop them in order.

    Parameters
    ----------
    nodes
        The nodes, started in this order.
    env
        Environment of every node process.
    log_dir
        Where each node's output (``<name>.log``) and pid file (``<name>.pid``) go.
    max_restarts
        Most restarts of one node within ``restart_window`` seconds; a node that exits
        once more is reported dead instead.
    restart_window
        Seconds over which restarts are counted.
    report
        Receives one line per restart or refused restart (default: standard error).
    """

    def __init__(self, nodes: list[NodeProcess], env: dict[str, str], log_dir: Path,
                 max_restarts: int = 3, restart_window: float = 60.0,
                 report: Callable[[str], object] | None = None) -> None:
        self.nodes = nodes
        self.env = env
        self.log_dir = log_dir
        self.max_restarts = max_restarts
        self.restart_window = restart_window
        self._report = report or (lambda line: print(line, file=sys.stderr, flush=True))

    def pid_path(self, node: NodeProcess) -> Path:
        return self.log_dir / f'{node.name}.pid'

    def start(self) -> None:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        for node in self.nodes:
            node.log_path = self.log_dir / f'{node.name}.log'
            self._launch(node, 'wb')

    def _launch(self, node: NodeProcess, mode: str) -> None:
        with open(node.log_path, mode) as log:
            if mode == 'ab':
                log.write(f'--- {time.strftime("%H:%M:%S")} restarted by the bringup ---\n'
                          .encode())
                log.flush()
            node.process = subprocess.Popen(node.command(), env=self.env, stdout=log,
                                            stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, start_new_session=True)
        pid_path = self.pid_path(node)
        tmp = pid_path.with_suffix('.pid.tmp')
        tmp.write_text(f'{node.process.pid}\n')
        tmp.replace(pid_path)

    def respawn_exited(self) -> list[NodeProcess]:
        """Restart the respawnable nodes that exited without being asked to; returns them.

        A node is not restarted after exit code 2 (it cannot start with its settings) or
        once it was restarted ``max_restarts`` times within ``restart_window`` seconds;
        it then stays dead (and :meth:`died` lists it).
        """
        restarted = []
        now = time.monotonic()
        for node in self.nodes:
            if not (node.respawn and not node.stopping and node.process is not None
                    and node.process.poll() is not None):
                continue
            code = node.process.returncode
            while node.restarts and now - node.restarts[0] > self.restart_window:
                node.restarts.popleft()
            why = None
            if code == STARTUP_ERROR:
                why = 'it cannot start with its settings'
            elif len(node.restarts) >= self.max_restarts:
                why = (f'it was restarted {len(node.restarts)} times in the last '
                       f'{self.restart_window:g} s')
            if why is not None:
                node.respawn = False
                self._report(f'bringup: node {node.name} exited with {exit_text(code)}; not '
                             f'restarting it: {why}')
                continue
            node.restarts.append(now)
            node.restart_count += 1
            self._launch(node, 'ab')
            restarted.append(node)
            self._report(f'bringup: node {node.name} exited with {exit_text(code)}; restarted '
                         f'it as pid {node.process.pid} (restart {len(node.restarts)} of at '
                         f'most {self.max_restarts} in {self.restart_window:g} s)')
        return restarted

    def died(self) -> list[NodeProcess]:
        """Nodes that exited without being asked to and will not be restarted, after
        restarting those that may be (:meth:`respawn_exited`). A respawnable node whose new
        process has exited already is not dead: the next call restarts it or gives up."""
        self.respawn_exited()
        return [n for n in self.nodes
                if n.process is not None and not n.stopping and not n.respawn
                and n.process.poll() is not None]

    def stop(self, timeout: float = 10.0) -> dict[str, int]:
        """SIGINT every node, wait up to ``timeout`` s, then SIGTERM, then SIGKILL; nodes
        marked ``stop_last`` (the recorder) only once all others have exited, so that they
        receive everything the others published.

        Returns each node's exit code (negative: killed by that signal).
        """
        running = [n for n in self.nodes if n.process is not None]
        for node in running:
            node.stopping = True
        for group in ([n for n in running if not n.stop_last],
                      [n for n in running if n.stop_last]):
            self._signal_until_gone(group, timeout)
        codes = {n.name: n.process.wait() for n in running}
        for node in running:
            self.pid_path(node).unlink(missing_ok=True)
        return codes

    @staticmethod
    def _signal_until_gone(group: list[NodeProcess], timeout: float) -> None:
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 3.0),
                          (signal.SIGKILL, 3.0)):
            alive = [n for n in group if n.process.poll() is None]
            if not alive:
                break
            for node in alive:
                try:
                    os.kill(node.process.pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline and any(n.process.poll() is None for n in alive):
                time.sleep(0.05)
