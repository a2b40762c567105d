"""A tiny dataset made once per test session by the real generation commands."""

import pytest

from dlmpc_ros.cli.data import main as data_main


@pytest.fixture(scope='session')
def quick_data(tmp_path_factory):
    """Made on two local Dask workers (test_data checks it equals the serial data)."""
    directory = tmp_path_factory.mktemp('data')
    assert data_main(['all', '--quick', '--no-progress', '--workers', '2', '--data-dir',
                      str(directory)]) == 0
    return directory
