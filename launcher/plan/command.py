"""The command line, environment and working directory of a node process: one function for `--args` and the supervisor.

What `launch --args NODE` prints is exactly what the supervisor runs (plus
`__log:=` when it gives the node a log file), because both call `node_command`.
The rules are roslaunch's (node_args.create_local_process_args and
core.setup_env): launch-prefix split like a shell, the executable found in the
package, `args` split like a shell, remaps `from:=to`, `__name:=`; the child
environment is ours plus ROS_MASTER_URI, ROS_NAMESPACE (the node's namespace,
never `__ns:=`) and the node's `<env>`s (a run's is given ROS_LOG_FILENAME too:
services.nodeservice).
"""

from __future__ import annotations

import os
import sys
from typing import Any, Dict, Iterable, List, Mapping, Tuple

from launcher.model import shellwords
from launcher.model.config import Node
from launcher.model.errors import LaunchError
from launcher.workspace.packages import BAG_MAIN
from launcher.workspace.roshome import ros_home

DEFAULT_MASTER_URI = "http://localhost:11311/"


class NodeCommand:
    """How to start one node."""

    # (not a dataclass: `dataclasses` costs ~5 ms of import on the way to a run's first node)
    __slots__ = ("argv", "env", "env_changes", "cwd")

    def __init__(self, argv: list[str], env: dict[str, str], env_changes: list[tuple[str, str]] | None = None,
                 cwd: str = ""):
        self.argv = argv
        self.env = env
        self.env_changes = env_changes if env_changes is not None else []
        self.cwd = cwd

    def __repr__(self) -> str:
        return "NodeCommand(argv=%r, env_changes=%r, cwd=%r)" % (self.argv, self.env_changes, self.cwd)

    def format_args(self) -> str:
        """The `--args` line: changed environment as KEY="value", then the command (roslaunch's format)."""
        return " ".join(['%s="%s"' % kv for kv in self.env_changes] + self.argv)


def master_uri(argv: Iterable[str], environ: Mapping[str, str]) -> str:
    """ROS_MASTER_URI as a node started by `launch` sees it: `__master:=`, then the environment, then the default."""
    for token in argv:
        if token.startswith("__master:="):
            return token[len("__master:="):]
    return environ.get("ROS_MASTER_URI") or DEFAULT_MASTER_URI


def node_env(node: Node, master_uri: str, environ: Mapping[str, str]) -> dict[str, str]:
    env = dict(environ)
    env["ROS_MASTER_URI"] = master_uri
    env.pop("ROS_NAMESPACE", None)
    ns = node.namespace[:-1] if node.namespace.endswith("/") else node.namespace
    if ns:
        env["ROS_NAMESPACE"] = ns
    for name, value in node.env_args:
        env[name] = value
    return env


# A node's environment and its changes, by what decides them: one dict for all the nodes with the same
# namespace and <env>s (a hundred copies of a robot's environment were ~0.5 MB of a launch's memory). Read only.
SharedEnvs = Dict[Tuple[str, str, Tuple[Tuple[str, str], ...]], Tuple[Dict[str, str], List[Tuple[str, str]]]]


def _split(text: str, what: str, node: Node) -> list[str]:
    try:
        return shellwords.split(text)
    except ValueError as e:
        raise LaunchError("node [%s]: cannot split %s [%s] like a shell: %s" % (node.full_name, what, text, e),
                          node.filename or None, node.line or None) from None


def node_command(node: Node, *, master_uri: str, environ: Mapping[str, str], packages: Any,
                 log_file: str | None = None, shared_envs: SharedEnvs | None = None) -> NodeCommand:
    """The command of `node`. Raises LaunchError naming the node if its executable cannot be found.

    `shared_envs`: the environments already made for the other nodes of the same `environ`, to share."""
    try:
        exe = packages.find_node(node.package, node.type)
    except LaunchError as e:
        raise LaunchError("node [%s] (%s/%s): %s" % (node.full_name, node.package, node.type, e.message),
                          node.filename or None, node.line or None) from None
    prefix = _split(node.launch_prefix, "launch-prefix", node) if node.launch_prefix else []
    args = _split(node.args, "args", node) if node.args else []
    # a built-in node (rosbag's record or play without rosbag): our module, on the python that runs us
    exe_argv = [sys.executable, "-m", "launcher.bag", node.type] if exe == BAG_MAIN else [exe]
    argv = prefix + exe_argv + args + ["%s:=%s" % r for r in node.remap_args] + ["__name:=%s" % node.name]
    if log_file:
        argv.append("__log:=%s" % log_file)
    key = (master_uri, node.namespace, node.env_args)
    made = shared_envs.get(key) if shared_envs is not None else None
    if made is None:
        env = node_env(node, master_uri, environ)
        made = env, [(k, v) for k, v in env.items() if environ.get(k) != v]
        if shared_envs is not None:
            shared_envs[key] = made
    env, changes = made
    cwd = os.path.dirname(exe) if node.cwd == "node" else ros_home(environ)
    return NodeCommand(argv=argv, env=env, env_changes=changes, cwd=cwd)
