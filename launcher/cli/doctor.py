"""`launcher doctor [pkg] [file.launch]`: the set-up mistakes newcomers hit most, found before a launch, each with its fix.

Each check says `ok`, `note` or `problem` in one line, and a problem says what
to do; a cause found at several nodes is one problem, with the nodes under it
and its fix once. Checks: which Python runs the launcher; the machine's host name, ROS_HOSTNAME and ROS_IP (they must
resolve to an address of this machine, or nodes cannot be reached: "Unable to
contact my own server"); ROS_MASTER_URI (its host resolves; a master answers, or
one can be started here); ROS_PACKAGE_PATH (each entry holds packages: an empty
one is usually an unsourced workspace); and, with a launch file, that it loads
and that every node's executable exists, is executable and has an interpreter
that exists ("cannot launch node of type"); and that a node script's
`#!/usr/bin/env python3` does not find, first on PATH, an interpreter that
cannot import what the system's python can (a venv's `bin` or a pyenv shim on
PATH: "No module named 'rospy'"). Exit status 1 when there is a problem.
"""

from __future__ import annotations

import os
import shlex
import shutil
import socket
import sys
import urllib.parse
from typing import Any, Mapping

import psutil

from launcher.workspace import nodepython
from launcher.plan.command import master_uri
from launcher.model.errors import LaunchError
from launcher.net.xmlrpc import call_blocking
from launcher.workspace.packages import ExecutableNotFound, PackageIndex, ros_paths
from launcher.xml import load, resolve_launch_arguments

OK, NOTE, PROBLEM = "ok", "note", "problem"


class Report:
    """The lines doctor prints. A cause is said once with its fix: the nodes it concerns are named under it
    (five nodes behind one venv's python3 are one problem with one fix), and a fix already given is not
    given again."""

    def __init__(self) -> None:
        self.problems = 0
        self._fixes: set[str] = set()
        # (level, cause, fix) -> the nodes it concerns, in the launch's order (dict: the causes' order too)
        self._nodes: dict[tuple[str, str, str], list[str]] = {}

    def say(self, level: str, text: str, fix: str = "") -> None:
        if level == PROBLEM:
            self.problems += 1
        print("%-8s %s" % (level, text))
        if fix:
            print("%-8s   fix: %s" % ("", "as above" if fix in self._fixes else fix))
            self._fixes.add(fix)

    def node(self, level: str, where: str, cause: str, fix: str = "") -> None:
        """A cause found at a node (`where`: file:line: node [name]); said by `nodes_done`, once per cause."""
        self._nodes.setdefault((level, cause, fix), []).append(where)

    def nodes_done(self) -> None:
        for (level, cause, fix), where in self._nodes.items():
            if len(where) == 1:
                self.say(level, "%s: %s" % (where[0], cause), fix)
            else:
                self.say(level, "%s: %d nodes\n%s" % (cause, len(where), "\n".join(
                    "%-8s   %s" % ("", w) for w in where)), fix)
        self._nodes.clear()


def main(argv: list[str]) -> int:
    if argv[:1] in (["-h"], ["--help"]):
        print("usage: launcher doctor [pkg] [file.launch] [name:=value ...]\n\n" + __doc__.split("\n\n", 1)[1])
        return 0
    environ = dict(os.environ)
    report = Report()
    check_launcher_python(report)
    local = _local_addresses()
    check_host_names(report, environ, local)
    check_master(report, environ, local)
    packages = PackageIndex(environ)
    check_package_path(report, environ, packages)
    check_python_on_path(report, environ)
    if argv:
        check_launch(report, argv, environ, packages)
    print("%d problem%s found" % (report.problems, "" if report.problems == 1 else "s"))
    return 1 if report.problems else 0


def check_launcher_python(report: Report) -> None:
    """Which Python runs the launcher (the nodes run their own: a `#!/usr/bin/env python3` finds the system's)."""
    version = "%d.%d.%d" % sys.version_info[:3]
    if sys.version_info < (3, 8):
        report.say(PROBLEM, "the launcher runs on Python %s (%s), older than it supports" % (version, sys.executable),
                   "install it with Python 3.8 or newer")
    else:
        report.say(OK, "the launcher runs on Python %s (%s)" % (version, sys.executable))


def _local_addresses() -> set[str]:
    return {a.address.split("%")[0] for addrs in psutil.net_if_addrs().values() for a in addrs}


def _resolve(host: str) -> set[str] | None:
    try:
        return {ai[4][0] for ai in socket.getaddrinfo(host, None)}
    except (OSError, UnicodeError):
        return None


def check_host_names(report: Report, environ: Mapping[str, str], local: set[str]) -> None:
    hostname = socket.gethostname()
    addresses = _resolve(hostname)
    if addresses is None:
        report.say(PROBLEM, "this machine's host name [%s] does not resolve" % hostname,
                   "add '127.0.1.1 %s' to /etc/hosts, or set ROS_IP to this machine's address" % hostname)
    elif not addresses & local:
        report.say(PROBLEM, "this machine's host name [%s] resolves to %s, no address of this machine"
                   % (hostname, ", ".join(sorted(addresses))),
                   "correct /etc/hosts, or set ROS_IP to one of %s" % ", ".join(sorted(local)))
    else:
        report.say(OK, "host name [%s] resolves to this machine" % hostname)
    ros_hostname = environ.get("ROS_HOSTNAME")
    if ros_hostname:
        addresses = _resolve(ros_hostname)
        if addresses is None:
            report.say(PROBLEM, "ROS_HOSTNAME [%s] does not resolve: nodes would advertise an address no one can "
                       "reach (\"Unable to contact my own server\")" % ros_hostname,
                       "set ROS_HOSTNAME to a name that resolves to this machine, or unset it")
        elif not addresses & local:
            report.say(PROBLEM, "ROS_HOSTNAME [%s] resolves to %s, no address of this machine"
                       % (ros_hostname, ", ".join(sorted(addresses))),
                       "set ROS_HOSTNAME to this machine's name, or ROS_IP to one of %s" % ", ".join(sorted(local)))
        else:
            report.say(OK, "ROS_HOSTNAME [%s] is this machine" % ros_hostname)
    ros_ip = environ.get("ROS_IP")
    if ros_ip:
        if ros_ip not in local:
            report.say(PROBLEM, "ROS_IP [%s] is no address of this machine (its addresses: %s)"
                       % (ros_ip, ", ".join(sorted(local))), "set ROS_IP to one of them, or unset it")
        else:
            report.say(OK, "ROS_IP [%s] is an address of this machine" % ros_ip)


def check_master(report: Report, environ: Mapping[str, str], local: set[str]) -> None:
    uri = master_uri([], environ)
    host = urllib.parse.urlsplit(uri).hostname or ""
    addresses = _resolve(host)
    if addresses is None:
        report.say(PROBLEM, "ROS_MASTER_URI [%s]: its host [%s] does not resolve" % (uri, host),
                   "use the master's address, or add its name to /etc/hosts")
        return
    try:
        call_blocking(uri, "getPid", "/launcher_doctor", timeout=3.0)
    except (OSError, ValueError) as e:
        if addresses & local or host == "localhost":
            report.say(NOTE, "no master answers at [%s]: `launch` will start one there" % uri)
        else:
            report.say(PROBLEM, "the master at [%s] does not answer (%s)" % (uri, getattr(e, "strerror", None) or e),
                       "start roscore (or `launch --core`) on %s, or point ROS_MASTER_URI at the right machine"
                       % host)
        return
    report.say(OK, "a master answers at [%s]" % uri)


def check_package_path(report: Report, environ: Mapping[str, str], packages: PackageIndex) -> None:
    if not environ.get("ROS_PACKAGE_PATH"):
        report.say(NOTE, "ROS_PACKAGE_PATH is not set: only the system's packages are found",
                   "source your workspace's devel/setup.bash (or install/setup.bash)")
    by_dir = packages.packages().values()
    for entry in ros_paths(environ)[:-1]:  # (the last is the system's share directory)
        root = os.path.abspath(entry)
        if not os.path.isdir(root):
            report.say(PROBLEM, "ROS_PACKAGE_PATH entry [%s] does not exist" % entry,
                       "remove it, or source the setup.bash of the workspace that is there now")
        elif not any(d == root or d.startswith(root + os.sep) for d in by_dir):
            report.say(PROBLEM, "ROS_PACKAGE_PATH entry [%s] holds no package" % entry,
                       "source your workspace's devel/setup.bash, or build the workspace first")
        else:
            report.say(OK, "ROS_PACKAGE_PATH entry [%s] holds packages" % entry)


def check_launch(report: Report, argv: list[str], environ: Mapping[str, str], packages: PackageIndex) -> None:
    try:
        files, args = resolve_launch_arguments(argv, packages)
        config = load(files, args, environ=environ, packages=packages)
    except LaunchError as e:
        report.say(PROBLEM, "the launch does not load: %s" % e)
        return
    report.say(OK, "the launch loads (%d node%s)" % (len(config.nodes), "" if len(config.nodes) == 1 else "s"))
    findable: dict[tuple[str, str], bool] = {}  # (interpreter, module) -> it finds it: once for all the nodes
    try:
        check_nodes(report, config, environ, packages, findable)
    finally:
        report.nodes_done()


def check_nodes(report: Report, config: Any, environ: Mapping[str, str], packages: PackageIndex,
                findable: dict[tuple[str, str], bool]) -> None:
    """Each node's executable and its interpreter, each cause told to the report with the node."""
    for node in config.nodes + config.tests:
        where = "%s:%d: node [%s]" % (node.filename, node.line, node.full_name)
        try:
            path = packages.find_node(node.package, node.type)
        except ExecutableNotFound as e:
            if e.not_executable:  # (roslaunch's "Make sure file exists" misleads: it does)
                report.node(PROBLEM, where, "the file [%s] is there but not executable" % e.not_executable,
                            "chmod +x %s" % shlex.quote(e.not_executable))
            else:
                report.node(PROBLEM, where, str(e).splitlines()[0],
                            "build the package, or correct type=\"%s\" (no such executable in [%s]%s)"
                            % (node.type, node.package, ": " + e.hint if e.hint else ""))
            continue
        except LaunchError as e:
            report.node(PROBLEM, where, str(e))
            continue
        problem = _shebang_problem(path, environ)
        if problem:
            report.node(PROBLEM, where, problem,
                        "correct the first line of %s, or install the interpreter it names" % path)
        else:
            check_node_python(report, where, path, environ, findable)


# What to do when a venv's or a version manager's python comes first on PATH (workspace/nodepython.py).
PATH_TRAP_FIX = ("take %s off PATH: put only `launch` and `launcher` on it (README: 'Installing for everyday use'), "
                 "or deactivate the venv / `pyenv shell system`")


def check_node_python(report: Report, where: str, script: str, environ: Mapping[str, str],
                      findable: dict[tuple[str, str], bool]) -> None:
    """A script whose `#!/usr/bin/env python3` finds an interpreter that lacks modules it imports which the
    system's python has: it would die with "No module named ..." at once."""
    trap = nodepython.trap(script, environ, findable)
    if trap is not None:
        interpreter, system, missing = trap
        # (the script is the node's; the cause, the interpreter PATH finds, is every such node's)
        report.node(PROBLEM, "%s (%s)" % (where, script), "'#!/usr/bin/env %s' finds %s first on PATH; that cannot "
                    "import %s (%s can)" % (os.path.basename(system), interpreter, ", ".join(missing), system),
                    PATH_TRAP_FIX % os.path.dirname(interpreter))


def check_python_on_path(report: Report, environ: Mapping[str, str]) -> None:
    """The same trap for any rospy node: `python3` on PATH is not the system's and cannot import rospy."""
    interpreter = nodepython.on_path("python3", environ)
    system = nodepython.system_python("python3")
    if interpreter is None or system is None or nodepython.is_system(interpreter):
        return
    if nodepython.lacking(interpreter, system, ["rospy"], environ, {}):
        report.say(NOTE, "python3 on PATH is %s, which cannot import rospy (%s can): a node starting with "
                   "'#!/usr/bin/env python3' dies at once" % (interpreter, system),
                   PATH_TRAP_FIX % os.path.dirname(interpreter))


def _shebang_problem(path: str, environ: Mapping[str, str]) -> str | None:
    """Why a script's `#!` line cannot start it ("cannot launch node of type"), or None."""
    try:
        with open(path, "rb") as f:
            head = f.readline(256)
    except OSError as e:
        return "cannot read %s: %s" % (path, e.strerror)
    if not head.startswith(b"#!"):
        return None  # a binary, or a script the kernel runs with /bin/sh
    words = head[2:].decode(errors="replace").split()
    if not words:
        return "%s has an empty '#!' line" % path
    interpreter = words[0]
    if not os.access(interpreter, os.X_OK):
        return "%s names the interpreter [%s], which does not exist or is not executable" % (path, interpreter)
    if os.path.basename(interpreter) == "env" and len(words) > 1 and not words[1].startswith("-"):
        if shutil.which(words[1], path=environ.get("PATH", os.defpath)) is None:
            return "%s runs [%s] through env, and no [%s] is on PATH" % (path, words[1], words[1])
    if head.endswith(b"\r\n"):
        return "%s has Windows line endings: its interpreter is [%s\\r]" % (path, interpreter)
    return None


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
