"""ROS recordings in and out, without ROS installed: bags (ROS 2 MCAP or sqlite3, ROS 1) as frame sources and an
MCAP of images, `vision_msgs` detections and Foxglove annotations as output (`docs/ros.md`).

The libraries (`rosbags`, `mcap`) are the `ros` extra, imported when a recording is opened: the plain install runs
without them.
"""

from __future__ import annotations

import importlib
from types import ModuleType

INSTALL_HINT = "pip install 'netapp-toolkit[ros]'"


def require(module: str, error: type[Exception], what: str) -> ModuleType:
    """`module`, or `error` with one line naming the extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise error(f"{what} needs the {module.split('.')[0]} package: {INSTALL_HINT}") from None
