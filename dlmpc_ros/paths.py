"""Where the package's shared files (config/, models/) are, in every install layout."""

from __future__ import annotations

import sys
from pathlib import Path

PACKAGE = 'dlmpc_ros'


def share_dir() -> Path:
    """The package's share directory: the ament index (colcon / ROS install), then
    ``<prefix>/share/dlmpc_ros`` (pip install), then the source tree (editable install)."""
    try:
        from ament_index_python.packages import (PackageNotFoundError,
                                                 get_package_share_directory)
        try:
            return Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, LookupError, ValueError, OSError):
            pass
    except ImportError:
        pass
    for candidate in (Path(sys.prefix) / 'share' / PACKAGE, Path(__file__).resolve().parents[1]):
        if (candidate / 'config').is_dir():
            return candidate
    raise FileNotFoundError(f'cannot find the {PACKAGE} share directory (config/ and models/); '
                            'reinstall the package')


def config_file(name: str) -> Path:
    """Path of ``config/<name>`` (e.g. ``laser_sim.yaml``)."""
    path = share_dir() / 'config' / name
    if not path.is_file():
        raise FileNotFoundError(f'missing configuration file {path}; reinstall the package')
    return path


def models_dir(override: str | Path = '') -> Path:
    """The directory of the model files: ``override`` if given, else ``<share>/models``."""
    return Path(override) if str(override) else share_dir() / 'models'
