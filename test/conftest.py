"""Shared fixtures: every ROS test process gets its own domain and log directory."""

from __future__ import annotations

import itertools
import os

import pytest

# Domains 100..232 are for tests, handed out in turn from a start that depends on the
# process id (pytest-xdist not used); a bringup run outside tests uses 87 by default.
_FIRST, _COUNT = 100, 133
_DOMAINS = (_FIRST + (os.getpid() + i) % _COUNT for i in itertools.count())


@pytest.fixture
def ros_env(tmp_path, monkeypatch) -> dict[str, str]:
    """Environment for a ROS test: a fresh domain id, localhost discovery, a log dir."""
    domain = next(_DOMAINS)
    env = {'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_LOG_DIR': str(tmp_path / 'ros-log')}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    return {**os.environ, **env}
