"""Parameter declaration and start-up error handling shared by the nodes."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import rclpy
from rclpy.duration import Duration
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from dlmpc_ros.ros.stop_signals import stop_on_signals
from dlmpc_ros.ros.teardown import TEARDOWN_GRACE, exit_after


class StartupError(ValueError):
    """Raised by a node's constructor for settings it cannot run with."""


def declare(node: Node, defaults: Mapping[str, object], descriptions: Mapping[str, str],
            read_only: frozenset[str] = frozenset(),
            ranges: Mapping[str, tuple[float, float]] | None = None) -> dict[str, object]:
    """Declare parameters with descriptions and, where ``ranges`` gives one, the range of
    values (``ros2 param describe`` shows it; rclpy refuses a value outside it, at start
    and at runtime); returns their values (overrides applied).

    A default of ``None`` declares a dynamically typed parameter that stays unset unless
    the user gives it.
    """
    values = {}
    ranges = ranges or {}
    for name, default in defaults.items():
        descriptor = ParameterDescriptor(description=descriptions.get(name, ''),
                                         read_only=name in read_only,
                                         dynamic_typing=default is None)
        if name in ranges:
            low, high = ranges[name]
            if isinstance(default, bool) or not isinstance(default, (int, float)):
                raise TypeError(f'a range needs a numeric parameter; {name} is {default!r}')
            if isinstance(default, int):
                descriptor.integer_range = [IntegerRange(from_value=int(low),
                                                         to_value=int(high), step=1)]
            else:
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(low), to_value=float(high), step=0.0)]
        try:
            values[name] = node.declare_parameter(name, default, descriptor).value
        except InvalidParameterValueException:
            if name not in ranges:
                raise
            given = getattr(node, '_parameter_overrides', {}).get(name)
            low, high = ranges[name]
            raise StartupError(
                f'parameter {name} = {given.value if given is not None else "?"} is outside '
                f'its range [{low:g}, {high:g}] ({descriptions.get(name, "")}); give a value '
                'in range') from None
    return values


def result(problems: list[str]) -> SetParametersResult:
    """A SetParametersResult that rejects with all problems joined as the reason."""
    return SetParametersResult(successful=not problems, reason='; '.join(problems))


#: Longest wait of a stopping node for its readers' acknowledgements, all its publishers
#: together [s] (a reader that keeps up acknowledges at once; a dead one never does).
ACK_WAIT = 3.0


def drain_until_quiet(executor, progress: Callable[[], int], quiet: float = 0.3,
                      longest: float = 10.0) -> None:
    """Spin ``executor`` until ``progress()`` (a count of messages handled) has not moved
    for ``quiet`` s, or ``longest`` s passed: a stopping node takes its backlog."""
    deadline = time.monotonic() + longest
    seen, since = progress(), time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - since < quiet:
        executor.spin_once(timeout_sec=0.05)
        now = progress()
        if now != seen:
            seen, since = now, time.monotonic()


def wait_for_acknowledgements(node: Node, budget: float = ACK_WAIT) -> None:
    """Let every publisher of ``node`` wait for its readers to acknowledge what it sent,
    ``budget`` s for all of them together."""
    deadline = time.monotonic() + budget
    for publisher in node.publishers:
        left = deadline - time.monotonic()
        if left <= 0:
            return
        publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))


def process_age() -> float:
    """Seconds since this process started (Linux /proc; NaN elsewhere)."""
    try:
        ticks = int(Path('/proc/self/stat').read_text().rsplit(')', 1)[1].split()[19])
        uptime = float(Path('/proc/uptime').read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float('nan')
    return uptime - ticks / os.sysconf('SC_CLK_TCK')


def run_node(make_node: Callable[[], Node], args: list[str] | None = None,
             executor_factory: Callable[[], object] | None = None) -> int:
    """Init rclpy, build the node, spin until SIGINT/SIGTERM, shutdown or ``node.finished``.

    At the end a node's ``drain(executor)`` (if it has one) takes what its subscriptions
    still hold, then its ``stop()`` runs, then its publishers wait (``ACK_WAIT`` s at most)
    for their readers to acknowledge what they sent.

    Returns the exit code: the node's ``exit_code`` attribute (0 if it has none), or 2 with
    one log line (no traceback) when the constructor raises :class:`StartupError`, a
    parameter has the wrong type, or the ROS arguments or parameter file cannot be read.
    A teardown of the executor, node and context that takes over ``TEARDOWN_GRACE`` s ends
    the process with that code (:mod:`dlmpc_ros.ros.teardown`).
    """
    requested = stop_on_signals()
    fatal = rclpy.logging.get_logger('dlmpc_ros').fatal
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except _rclpy.UnknownROSArgsError as err:
        fatal(f'cannot start: unknown ROS arguments {err}; after --ros-args give '
              '-p NAME:=VALUE or --params-file FILE')
        return 2
    except _rclpy.RCLError as err:
        fatal(f'cannot start: fix the command-line parameters or the parameter file: {err}')
        return 2
    node = None
    code = 0
    executor = None
    try:
        node = make_node()
        executor = (executor_factory or rclpy.executors.SingleThreadedExecutor)()
        executor.add_node(node)
        node.get_logger().info(f'ready {process_age():.2f} s after its process started '
                               f'({time.process_time():.2f} s of CPU)')
        while not requested.is_set() and rclpy.ok() and not getattr(node, 'finished', False):
            executor.spin_once(timeout_sec=0.1)
        code = getattr(node, 'exit_code', 0)
    except (StartupError, InvalidParameterTypeException, InvalidParameterValueException) as err:
        fatal(f'cannot start: {err}')
        code = 2
    except ExternalShutdownException:
        pass
    finally:
        if node is not None:
            drain = getattr(node, 'drain', None)
            if drain is not None and executor is not None and rclpy.ok():
                drain(executor)
            stop = getattr(node, 'stop', None)
            if stop is not None:
                stop()
            if rclpy.ok():  # the last messages reach the readers before the node goes
                wait_for_acknowledgements(node)
        # the work is done: a middleware teardown that hangs must not keep the process
        with exit_after(TEARDOWN_GRACE, 1 if sys.exc_info()[0] is not None else code):
            if executor is not None:
                executor.shutdown()
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
    return code
