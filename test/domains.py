"""ROS domain ids for tests: 100..232, a disjoint share for each pytest-xdist worker.

Each worker hands out the ids of its share in turn, from a start that depends on its
process id (another test run on the machine likely starts elsewhere); a bringup run
outside tests uses 87 by default."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator

FIRST, COUNT = 100, 133


def _domains() -> Iterator[int]:
    worker = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw'))
    share = COUNT // int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))
    if share < 1:
        raise RuntimeError(f'at most {COUNT} test workers: each needs its own ROS domain ids')
    start = FIRST + worker * share
    return (start + (os.getpid() + i) % share for i in itertools.count())


_DOMAINS = _domains()


def next_domain() -> int:
    """A domain id no other test of this run is using now."""
    return next(_DOMAINS)
