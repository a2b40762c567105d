"""ROS 2 nodes of dlmpc_ros, one per module, each with a ``main``.

Importing this package (every node process does, first) makes SIGINT and SIGTERM end the
process quietly with exit code 0 until its node takes the signals over
(:func:`dlmpc_ros.ros.params.run_node`): a Ctrl-C during the seconds of start-up (imports,
loading models) stops a node without a traceback.
"""

import signal
import sys


def _stop_quietly(signum, frame) -> None:
    sys.exit(0)


for _signal in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signal, _stop_quietly)
