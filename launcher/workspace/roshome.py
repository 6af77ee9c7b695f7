"""Where ROS keeps its files on this machine: `ROS_HOME` and the log root, as rospkg decides them; our caches there."""

from __future__ import annotations

import marshal
import os

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Mapping


# What a launch keeps of itself in its run's log directory, for after the run (services/runrecord.py writes them,
# `launcher report` reads them): its files, arguments, environment and packages; the parameters it set, as YAML.
RUN_RECORD_FILE = "launcher-run.json"
PARAMS_FILE = "launcher-params.yaml"
# the environment variables that matter to a ROS run: these names, and those starting with a prefix of ROS_ENV_PREFIXES
ROS_ENV_NAMES = ("PATH", "PYTHONPATH", "LD_LIBRARY_PATH", "CMAKE_PREFIX_PATH", "PKG_CONFIG_PATH", "PYTHONHOME",
                 "VIRTUAL_ENV", "HOME", "USER", "LANG", "LC_ALL", "TZ", "DISPLAY", "NOTIFY_SOCKET", "JOURNAL_STREAM")
ROS_ENV_PREFIXES = ("ROS", "CATKIN", "GAZEBO", "LAUNCHER_", "ROSLAUNCH_", "ROSCONSOLE_", "RMW_")


def ros_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """The variables of `environ` that matter to a ROS run (what `launcher report` keeps), by name."""
    return {k: v for k, v in sorted(environ.items()) if k in ROS_ENV_NAMES or k.startswith(ROS_ENV_PREFIXES)}


def ros_home(environ: Mapping[str, str]) -> str:
    """`$ROS_HOME`, default `~/.ros` (rospkg.get_ros_home)."""
    return environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")


def log_root(environ: Mapping[str, str]) -> str:
    """`$ROS_LOG_DIR`, default `$ROS_HOME/log` (rospkg.get_log_dir)."""
    return environ.get("ROS_LOG_DIR") or os.path.join(ros_home(environ), "log")


# -- the caches launcher keeps under ROS_HOME (workspace/crawlcache.py, params/yamlcache.py) ----------------------------
# One marshalled (version, entries) pair per file. The files are the user's own, as rospack's cache is:
# marshal is not meant for data from strangers, and a file that does not load is no cache.

def read_cache(path: str | None, version: int) -> dict:
    """The entries of a cache file, or {} when there is none or it is of another version or unreadable."""
    if path:
        try:
            with open(path, "rb") as f:
                found_version, entries = marshal.loads(f.read())  # (marshal.load(f) reads piece by piece: slow)
            if found_version == version and type(entries) is dict:
                return entries
        except (OSError, EOFError, ValueError, TypeError):
            pass
    return {}


def write_cache(path: str | None, version: int, entries: dict) -> None:
    """Replace a cache file atomically (a launch reading it meanwhile sees the old one or the new one).
    Best effort: a read-only ROS_HOME only costs the next launch the work the cache would have saved."""
    if not path:
        return
    tmp = "%s.%d.tmp" % (path, os.getpid())
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(tmp, "wb") as f:
            marshal.dump((version, entries), f)
        os.replace(tmp, path)
    except OSError:
        try:
            os.unlink(tmp)
        except OSError:
            pass
