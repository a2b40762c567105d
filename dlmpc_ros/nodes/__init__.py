"""ROS 2 nodes of dlmpc_ros, one per module, each with a ``main``.

Importing this package (every node process does, first) makes SIGINT and SIGTERM end the
process quietly with exit code 0 until its node takes the signals over
(:func:`dlmpc_ros.ros.params.run_node`): a Ctrl-C during the seconds of start-up (imports,
loading models) stops a node without a traceback.
"""

import os
import signal
import sys


def _stop_quietly(signum, frame) -> None:
    # os._exit, not sys.exit: a SystemExit raised while the interpreter runs a callback
    # (importlib's module-lock cleanup, mid-import) is printed as "Exception ignored"
    # with a traceback and swallowed, and the node would start anyway. Before its node
    # exists the process holds nothing that needs closing but its output.
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(0)


for _signal in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signal, _stop_quietly)
