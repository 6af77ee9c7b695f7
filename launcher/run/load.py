"""A launch's plan made on this machine: its files read, its other hosts looked up, its needs of this machine checked.

The plan itself (`plan.plan.Plan`) is a pure description; making one reads
the environment: the launch files and packages (`xml.load`), the master URI,
which of the launch's machines are other hosts (`plan.machines`: a lookup per
machine), and what the other machines need of this one (`check_plan`: an
address they can reach, what OpenSSH can do). `launch` makes one at its start
(`begin_plan`: in a process of its own, begun before the run's modules are
imported; `core_plan` for roscore), a reload again (`plan_again`),
`launcher test` one per test (`plan_for`). The XML loader is imported by the
functions that read files: a launch whose plan was made apart never loads
it; nor does this module import asyncio (the master's and the run record's
modules are imported where they are used), so `launch` can fork the reader
of its files before it imports the run.
"""

from __future__ import annotations

import os
import sys
from typing import Any, Callable, Iterator, Mapping

from launcher.net.hostname import advertised_host
from launcher.net.xmlrpc_codec import unsendable
from launcher.model.config import LaunchConfig
from launcher.model.errors import LaunchError
from launcher.model.names import AnonNames
from launcher.model.runopts import RunOptions
from launcher.model.units import LOG_CHECK_THRESHOLD, parse_size
from launcher.output import console
from launcher.plan.command import master_uri
from launcher.plan.machines import remote_machines
from launcher.plan.plan import Plan
from launcher.run.apart import Apart, begin_apart
from launcher.workspace.packages import PackageIndex


def core_plan(opts: RunOptions) -> Plan:
    """roscore: an empty launch, our master on -p or ROS_MASTER_URI's port."""
    from launcher.services import masterlink
    environ = dict(os.environ)
    port = masterlink.master_port(opts.port, environ)
    uri_port = masterlink.master_port(None, environ)
    if environ.get("ROS_MASTER_URI") and uri_port != port:
        print("WARNING: ROS_MASTER_URI port [%d] does not match this roscore [%d]" % (uri_port, port),
              file=sys.stderr)
    return Plan(LaunchConfig(), "", environ, core=True, core_port=port)


def begin_plan(opts: RunOptions) -> Apart:
    """`load_plan` begun in a process of its own (run/apart.py), with the text of the run's launcher-params.yaml: the
    launch keeps neither the XML loader nor PyYAML; its `result()` is the plan. Its `$(anon)` names are the
    launch's (with its pid)."""
    launch_pid = os.getpid()

    def make() -> Plan:
        from launcher.services import runrecord
        plan = load_plan(opts, AnonNames(launch_pid))
        plan.params_text = runrecord.params_text(plan.config)
        return plan
    return begin_apart(make, opts.verbose)


def load_plan(opts: RunOptions, anon_names: AnonNames | None = None) -> Plan:
    """Read the launch files into a plan, checked; LaunchError (file and line) for bad input."""
    from launcher.xml import load, resolve_launch_arguments
    environ = dict(os.environ)
    warn = lambda msg: console.printerrlog("WARNING: %s" % msg)  # noqa: E731
    packages = PackageIndex(environ, warn=warn)
    files, argv = resolve_launch_arguments(list(opts.positional), packages)
    if not files:
        raise LaunchError("you must specify at least one input file")
    anon_names = AnonNames() if anon_names is None else anon_names
    config = load(files, argv, environ=environ, packages=packages, warn=warn, anon_names=anon_names)
    uri = master_uri(argv, environ)
    if opts.port:
        if not 0 < opts.port < 65536:
            raise LaunchError("invalid port assignment: %s" % opts.port)
        uri = "http://%s:%d/" % (advertised_host(environ), opts.port)
    threshold = LOG_CHECK_THRESHOLD
    if opts.log_check_threshold:
        try:
            threshold = parse_size(opts.log_check_threshold)
        except ValueError as e:
            raise LaunchError("--log-check-threshold: %s" % e) from None
    try:
        log_max_size = parse_size(opts.log_max_size or "0")
    except ValueError as e:
        raise LaunchError("--log-max-size: %s" % e) from None
    plan = plan_for(config, uri, environ, packages=packages, log_threshold=threshold, log_max_size=log_max_size,
                    files=files, argv=argv, anon_names=anon_names)
    check_plan(plan, opts)
    return plan


def plan_again(old: Plan, opts: RunOptions, given: list[str], warn: Callable[[str], None]) -> Plan:
    """The same launch read again (a reload): its files, its args with `given` ones replacing theirs, its
    environment, its master URI, its `$(anon)` names; a fresh package index (packages built since count).
    LaunchError for bad input, as at the start. Runs off the loop (it reads files)."""
    from launcher.xml import load
    names = {a.split(":=", 1)[0] for a in given}
    argv = [a for a in old.argv if a.split(":=", 1)[0] not in names] + list(given)
    packages = PackageIndex(old.environ, warn=warn)
    config = load(old.files, argv, environ=old.environ, packages=packages, warn=warn, anon_names=old.anon_names)
    plan = plan_for(config, old.master_uri, old.environ, packages=packages, log_threshold=old.log_threshold,
                    log_max_size=old.log_max_size, files=old.files, argv=argv, anon_names=old.anon_names)
    check_plan(plan, opts)
    return plan


def plan_for(config: LaunchConfig, master_uri: str, environ: Mapping[str, str], **fields: Any) -> Plan:
    """The plan of a loaded launch on this machine: the machines of its nodes that are other hosts looked up,
    once per machine (plan.machines)."""
    return Plan(config, master_uri, environ, remote_machines=remote_machines(config, environ), **fields)


def unsendable_params(config: LaunchConfig) -> Iterator[LaunchError]:
    """Each parameter XML-RPC cannot send (a YAML date or null, an integer beyond 32 bits), at its tag: roslaunch's
    launch fails on it as it sets it; `launcher check` reports it."""
    for param in config.params.values():
        problem = unsendable(param.value)
        if problem:
            yield LaunchError("parameter [%s] cannot be set: %s" % (param.key, problem), param.filename or None,
                              param.line or None)


def check_plan(plan: Plan, opts: RunOptions) -> None:
    """The plan's checks (plan.plan.Plan.check_nodes), then what the other machines need of this one: OpenSSH's
    limits, addresses they can reach (this machine's ROS address), the supervision extensions their
    roslaunch child cannot apply (warned about)."""
    plan.check_nodes(opts.required)
    for error in unsendable_params(plan.config):
        raise error
    if opts.local:
        return
    config = plan.config
    machines = {config.machines[n.machine_name] for n in config.nodes if plan.remote(n)}
    if machines:
        # (the remote machinery is imported only by a launch with other machines' nodes)
        from launcher.remote import ssh
        from launcher.plan.remote import check_addresses, policy_warnings
        for machine in sorted(machines, key=lambda m: m.name):
            ssh.check_machine(machine)
        check_addresses(plan.master_uri, advertised_host(plan.environ), sorted(machines, key=lambda m: m.name))
        for node in config.nodes:
            if plan.remote(node):
                for warning in policy_warnings(node, config.machines[node.machine_name]):
                    console.printerrlog("WARNING: %s" % warning)
