"""Shared test setup: where the real ROS parts are, and the rule that CI never skips them."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from helpers import ROS_PATH, ROS_PYTHON


def _ros_available() -> str | None:
    """None if Debian's rospy and the ROS tools can run here, else why not."""
    if not os.path.exists(ROS_PYTHON):
        return "%s not found" % ROS_PYTHON
    try:
        subprocess.run([ROS_PYTHON, "-c", "import rospy, rosgraph"], check=True,
                       capture_output=True, timeout=60)
    except (subprocess.SubprocessError, OSError):
        return "rospy does not import under %s" % ROS_PYTHON
    for tool in ("rosnode", "rostopic", "rosparam", "rosservice"):
        if shutil.which(tool, path=ROS_PATH) is None:
            return "%s not installed" % tool
    return None


_ROS_MISSING: str | None | bool = False


def ros_missing() -> str | None:
    global _ROS_MISSING
    if _ROS_MISSING is False:
        _ROS_MISSING = _ros_available()
    return _ROS_MISSING  # type: ignore[return-value]


@pytest.fixture(scope="session")
def ros_env():
    """Skip (or, under REQUIRE_ROS=1 as in CI, fail) when real ROS parts are missing."""
    why = ros_missing()
    if why:
        if os.environ.get("REQUIRE_ROS") == "1":
            pytest.fail("integration tests cannot run: %s (REQUIRE_ROS=1)" % why)
        pytest.skip("real ROS parts missing: %s" % why)
    return {"python": ROS_PYTHON, "path": ROS_PATH}


def skip_unless_ros_required(why: str) -> None:
    """Skip for a missing ROS part, except under REQUIRE_ROS=1 (CI), where it is a failure."""
    if os.environ.get("REQUIRE_ROS") == "1":
        pytest.fail("cannot run: %s (REQUIRE_ROS=1)" % why)
    pytest.skip(why)


@pytest.fixture(scope="session")
def ros_part_missing():
    """`ros_part_missing(why)`: skip for a missing ROS part, fail instead under REQUIRE_ROS=1."""
    return skip_unless_ros_required
