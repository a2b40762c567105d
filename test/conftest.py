"""Shared fixtures: every ROS test process gets its own domain and log directory."""

from __future__ import annotations

import itertools
import os

import pytest

# Domains 150..232 are for tests; each test module gets its own (pytest-xdist not used).
_DOMAINS = itertools.count(150 + (os.getpid() % 40))


@pytest.fixture
def ros_env(tmp_path, monkeypatch) -> dict[str, str]:
    """Environment for a ROS test: a fresh domain id, localhost discovery, a log dir."""
    domain = next(_DOMAINS)
    if domain > 232:
        pytest.fail('ran out of test ROS domain ids')
    env = {'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_LOG_DIR': str(tmp_path / 'ros-log')}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    return {**os.environ, **env}
