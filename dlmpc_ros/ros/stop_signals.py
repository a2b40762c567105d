"""SIGINT and SIGTERM as a flag: for the ROS processes, and for the bringup before it loads
rclpy (this module does not import it)."""

from __future__ import annotations

import signal
import threading


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM instead of raising KeyboardInterrupt.

    An exception raised by a signal in the middle of rclpy's message conversion turns
    into an unrelated RuntimeError, and one raised while a C extension initialises fails
    its import; a flag checked between spins avoids both.
    """
    requested = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: requested.set())
    return requested
