"""What the benchmark scripts share: Debian's ROS tools first on PATH, and a free port.

The scripts run as `python3 benchmarks/NAME.py`, so this folder is on their import path.
"""

from __future__ import annotations

import socket

ROS_PATH = "/usr/bin:/bin:/usr/sbin:/sbin"  # Debian's ROS scripts need Debian's python: its bin first


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
