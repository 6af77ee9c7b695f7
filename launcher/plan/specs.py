"""What runs for each local node of a launch: its `ProcessSpec` (command line, output, log files, restart settings)."""

from __future__ import annotations

import os
from typing import Any, Callable, Mapping

from launcher.process.command import node_command
from launcher.model.errors import LaunchError
from launcher.model.names import ns_join
from launcher.output import console
from launcher.process.spawn import ProcessSpec
from launcher.model.runopts import RunOptions


def node_specs(config: Any, master_uri: str, environ: Mapping[str, str], packages: Any,
               is_remote: Callable[[Any], bool], *, opts: RunOptions, run_dir: str,
               first_number: int, process_names: Mapping[str, str] | None = None,
               ) -> tuple[list[ProcessSpec], list[tuple[str, bool]]]:
    """What to run for each local node (numbered as roslaunch's processes, after `first_number`), and the
    (name, required) of nodes that cannot be prepared (each reported by name here). `opts` gives the
    command line's --screen, --log and --required; `process_names` the process names nodes keep (a node a
    reload restarts keeps its name, its log files and its place in roslaunch's numbering)."""
    if config.tests:
        # roslaunch skips <test> tags without a word; say so, they are the user's
        console.printlog("ignoring %d <test> node(s) (%s): run them with `launcher test` (or rostest)"
                         % (len(config.tests), ", ".join(t.test_name or t.name for t in config.tests)))
    specs: list[ProcessSpec] = []
    failed: list[tuple[str, bool]] = []
    number = first_number
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
                                   log_file=os.path.join(run_dir, log_name + ".log"))
        except LaunchError as e:
            console.printerrlog("ERROR: cannot launch node of type [%s/%s]: %s" % (node.package, node.type, e))
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
