"""Shared fixtures: every ROS test process gets its own domain and log directory."""

from __future__ import annotations

import os

import pytest

from test.domains import next_domain


@pytest.fixture
def ros_env(tmp_path, monkeypatch) -> dict[str, str]:
    """Environment for a ROS test: a fresh domain id, localhost discovery, a log dir."""
    domain = next_domain()
    env = {'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_LOG_DIR': str(tmp_path / 'ros-log')}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    return {**os.environ, **env}
