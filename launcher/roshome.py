"""Where ROS keeps its files on this machine: `ROS_HOME` and the log root, as rospkg decides them."""

from __future__ import annotations

import os
from typing import Mapping


def ros_home(environ: Mapping[str, str]) -> str:
    """`$ROS_HOME`, default `~/.ros` (rospkg.get_ros_home)."""
    return environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")


def log_root(environ: Mapping[str, str]) -> str:
    """`$ROS_LOG_DIR`, default `$ROS_HOME/log` (rospkg.get_log_dir)."""
    return environ.get("ROS_LOG_DIR") or os.path.join(ros_home(environ), "log")
