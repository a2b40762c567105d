"""A deadline on a node's middleware teardown that holds even while Python cannot run.

Fast DDS 2.14 sometimes never returns from destroying a node's participant: in about 450
stops of a bringup here, a node twice had to be killed 13 s after the stop began
(``laser_sim`` once, ``drift_injector`` once), and the run was reported unclean; the one
caught in the act spun in ``DomainParticipant::set_listener`` under ``rcl_node_fini``,
holding the GIL, so no Python thread, signal handler or timer could end it.
:func:`exit_after` arms a POSIX timer whose expiry calls the C library's ``_exit`` on a
thread of its own (``SIGEV_THREAD``): once a node has done its work (drained, stopped,
its last messages acknowledged), a teardown that overruns ends the process with the
node's own exit code instead of hanging. Seen once in about 170 further stops: a stop
of 8.3 s (3 s waiting for acknowledgements, then this 5 s deadline) with exit code 0.
Linux (glibc 2.34 or later) only; elsewhere :func:`exit_after` arms nothing.
"""

from __future__ import annotations

import ctypes
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: Seconds a node's teardown (executor, node, context) may take before the process ends
#: without it.
TEARDOWN_GRACE = 5.0

_LIBC = ctypes.CDLL(None, use_errno=True)

_CLOCK_MONOTONIC = 1
_SIGEV_THREAD = 2


class _SigVal(ctypes.Union):
    _fields_ = [('sival_int', ctypes.c_int), ('sival_ptr', ctypes.c_void_p)]


class _SigEventThread(ctypes.Structure):
    """glibc's ``struct sigevent`` (64 bytes) with its ``SIGEV_THREAD`` members."""

    _fields_ = [('sigev_value', _SigVal), ('sigev_signo', ctypes.c_int),
                ('sigev_notify', ctypes.c_int), ('function', ctypes.c_void_p),
                ('attributes', ctypes.c_void_p), ('_pad', ctypes.c_byte * 32)]


class _TimeSpec(ctypes.Structure):
    _fields_ = [('tv_sec', ctypes.c_long), ('tv_nsec', ctypes.c_long)]


class _ITimerSpec(ctypes.Structure):
    _fields_ = [('it_interval', _TimeSpec), ('it_value', _TimeSpec)]


@contextmanager
def exit_after(seconds: float, code: int) -> Iterator[bool]:
    """Within the block, end this process with exit status ``code`` (0-255) once
    ``seconds`` have passed; no cleanup runs (as ``os._exit``), so Python's standard
    output and error are flushed on entry. Yields whether the deadline is armed; leaving
    the block disarms it."""
    if not 0 <= code <= 255 or not seconds > 0:
        raise ValueError(f'exit_after needs seconds > 0 and a code in 0-255, got '
                         f'{seconds}, {code}')
    sys.stdout.flush()
    sys.stderr.flush()
    timer = _arm(seconds, code) if sys.platform.startswith('linux') else None
    try:
        yield timer is not None
    finally:
        if timer is not None:
            _LIBC.timer_delete(timer)


def _arm(seconds: float, code: int) -> ctypes.c_void_p | None:
    """A POSIX timer that calls ``_exit(code)`` on its own thread in ``seconds``."""
    try:
        create, settime, exit_now = _LIBC.timer_create, _LIBC.timer_settime, _LIBC._exit
    except AttributeError:  # glibc before 2.34 keeps the timers in librt
        return None
    event = _SigEventThread(sigev_value=_SigVal(sival_int=code), sigev_notify=_SIGEV_THREAD,
                            function=ctypes.cast(exit_now, ctypes.c_void_p).value)
    timer = ctypes.c_void_p()
    if create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
        return None
    whole = int(seconds)
    spec = _ITimerSpec(it_value=_TimeSpec(whole, int((seconds - whole) * 1e9)))
    if settime(timer, 0, ctypes.byref(spec), None) != 0:
        _LIBC.timer_delete(timer)
        return None
    return timer
