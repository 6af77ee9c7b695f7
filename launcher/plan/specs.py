"""What runs for each local node of a launch: its `ProcessSpec` (command line, output, log files, restart settings).

A `ProcessSpec` is a node's `NodeCommand` (the very object `launch --args` prints, so what it prints is what
runs) plus how the process is supervised: its roslaunch process name, where its output goes, respawn and
required. The runner (`process/`) starts what the plan made; the plan imports nothing of the runner's."""

from __future__ import annotations

import os
from typing import Any, Callable, Mapping

from launcher.model.config import NodePolicy
from launcher.model.errors import LaunchError
from launcher.model.names import ns_join
from launcher.model.runopts import RunOptions
from launcher.plan.command import NodeCommand, SharedEnvs, node_command

DEFAULT_POLICY = NodePolicy()  # a node with none of the extension attributes: roslaunch's behaviour


class ProcessSpec:
    """One node to supervise: its command (`launcher.plan.command.node_command`) and how it is run."""

    # (a plain class rather than a dataclass: `dataclasses` costs ~4 ms of import on the way to the
    # first spawn)
    __slots__ = ("name", "command", "output", "stdout_path", "log_dir", "respawn", "respawn_delay", "required",
                 "node_name", "policy")

    def __init__(self, name: str, command: NodeCommand, stdout_path: str | None = None,
                 log_dir: str | None = None, respawn: bool = False, respawn_delay: float = 0.0,
                 required: bool = False, node_name: str | None = None, policy: NodePolicy | None = None,
                 output: str | None = None):
        self.name = name  # roslaunch's process name, e.g. "robot/driver-2"
        self.node_name = node_name or "/" + name  # the ROS node name, e.g. "/robot/driver": how status names it
        self.policy = policy if policy is not None else DEFAULT_POLICY  # restart policy, readiness, limits
        self.command = command
        # output="log": the node writes its stdout to `stdout_path` itself; output="screen": to the terminal,
        # through the launcher, which keeps a copy in `stdout_path` (output/screen.py)
        self.output = output or ("log" if stdout_path else "screen")
        self.stdout_path = stdout_path  # None: no file (a screen node then inherits the terminal unless relayed)
        self.log_dir = log_dir  # for the "log file:" hint after a death
        self.respawn = respawn
        self.respawn_delay = respawn_delay
        self.required = required

    def __repr__(self) -> str:
        return "ProcessSpec(%s)" % ", ".join("%s=%r" % (k, getattr(self, k)) for k in self.__slots__)

    @property
    def argv(self) -> list[str]:
        return self.command.argv

    @property
    def log_name(self) -> str:
        return self.name.replace("/", "-")


def node_specs(config: Any, master_uri: str, environ: Mapping[str, str], packages: Any,
               is_remote: Callable[[Any], bool], *, opts: RunOptions, run_dir: str,
               first_number: int, process_names: Mapping[str, str] | None = None,
               log: Callable[[str], None], log_error: Callable[[str], None],
               ) -> tuple[list[ProcessSpec], list[tuple[str, bool]]]:
    """What to run for each local node (numbered as roslaunch's processes, after `first_number`), and the
    (name, required) of nodes that cannot be prepared (each reported by name here). `opts` gives the
    command line's --screen, --log and --required; `process_names` the process names nodes keep (a node a
    reload restarts keeps its name, its log files and its place in roslaunch's numbering). What is said of the
    launch's nodes goes to `log` and `log_error` (the run's console: the plan writes nothing itself)."""
    if config.tests:
        # roslaunch skips <test> tags without a word; say so, they are the user's
        log("ignoring %d <test> node(s) (%s): run them with `launcher test` (or rostest)"
            % (len(config.tests), ", ".join(t.test_name or t.name for t in config.tests)))
    specs: list[ProcessSpec] = []
    failed: list[tuple[str, bool]] = []
    number = first_number
    shared_envs: SharedEnvs = {}
    for node in config.nodes:
        if is_remote(node):
            continue  # its machine's child runs it (launcher.remote), or --local leaves it out
        name = process_names.get(node.full_name) if process_names else None
        if name is None:
            number += 1
            name = ("%s-%d" % (ns_join(node.namespace, node.name), number)).lstrip("/")
        log_name = name.replace("/", "-")
        required = node.required or opts.required
        try:
            command = node_command(node, master_uri=master_uri, environ=environ, packages=packages,
                                   log_file=os.path.join(run_dir, log_name + ".log"), shared_envs=shared_envs)
        except LaunchError as e:
            log_error("ERROR: cannot launch node of type [%s/%s]: %s" % (node.package, node.type, e))
            failed.append((name, required))
            continue
        output = node.output or "log"
        if opts.screen:
            output = "screen"
        elif opts.log:
            output = "log"
        specs.append(ProcessSpec(
            name, command,
            output=output, stdout_path=os.path.join(run_dir, log_name + "-stdout.log"),
            log_dir=run_dir, respawn=node.respawn, respawn_delay=node.respawn_delay, required=required,
            node_name=ns_join(node.namespace, node.name), policy=node.policy))
    return specs, failed


def packages_of(config: Any, specs: list[ProcessSpec]) -> dict[str, str]:
    """process name -> the node's package (roslaunch's process_info reports it)."""
    by_node = {ns_join(n.namespace, n.name): n.package for n in config.nodes}
    return {spec.name: by_node.get(spec.node_name, "") for spec in specs}
