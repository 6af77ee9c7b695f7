"""`launcher install|uninstall|installed`: a launch as a systemd service (robot_upstart's job, with `launch` as a notify service).

`unit_text(UnitOptions)` is the unit, a pure function of the options, so that
`--dry-run` prints exactly what is written. The unit makes systemd supervise
the launch end to end: `Type=notify` (active once the nodes are up:
services/systemd.py), `WatchdogSec=` (a stuck launch is restarted),
`Restart=on-failure` with a start-rate limit, and a stop that leaves our own
escalation in charge: `KillSignal=SIGINT` to the launch alone (`KillMode=mixed`),
which stops its nodes SIGINT -> SIGTERM -> SIGKILL, each on its own clock,
and `TimeoutStopSec=` longer than that escalation, after which systemd kills
whatever is left. systemd itself is never driven silently: the commands that
enable the unit are printed, not run.
"""

from __future__ import annotations

import argparse
import os
import pwd
import re
import subprocess
import sys
from typing import NamedTuple

from launcher import __version__
from launcher.model.runopts import RunOptions

MARK = "# Written by `launcher install`"  # the first line of our units: only these are replaced or removed
DEFAULT_WATCHDOG_S = 30  # systemd restarts a launch whose loop has not pinged for this long
STOP_MARGIN_S = 5  # TimeoutStopSec beyond the launch's own escalation (its own teardown: master, logs)
# TimeoutStartSec: the launch sends READY=1 after at most its ready timeout (60 s, --ready-timeout); systemd's
# own start timeout stays this much above it (or else systemd, not the launch, would decide the start failed)
START_TIMEOUT_S = 120
START_MARGIN_S = 60
# a system PATH: no virtual environment's or pyenv's python3 before the system's, whose rospy the nodes import
SYSTEM_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
NAME_OK = re.compile(r"[A-Za-z0-9:_.\\-]+")


class UnitOptions(NamedTuple):
    name: str
    launch: tuple[str, ...]  # the launch command: the executable, then its arguments
    description: str = ""
    files: tuple[str, ...] = ()  # what the unit runs, for `launcher installed`
    user: str = ""  # User= (a system unit); its groups come with it (systemd calls initgroups)
    ros_home: str = ""
    setup: str = ""  # a workspace's setup.bash, sourced before the launch
    env: tuple[tuple[str, str], ...] = ()
    env_files: tuple[str, ...] = ()
    ros_ip_from: str = ""  # a network interface whose IPv4 address becomes ROS_IP when the service starts
    after: tuple[str, ...] = ()
    master: str = ""  # an external master's URI ("": the launch's own)
    system: bool = True
    watchdog_s: int = DEFAULT_WATCHDOG_S
    sigint_timeout: float = RunOptions().sigint_timeout
    sigterm_timeout: float = RunOptions().sigterm_timeout
    ready_timeout: float = RunOptions().ready_timeout


def quote(arg: str) -> str:
    """One word of a systemd command line: quoted when it must be, with `%` and `$` kept literal."""
    arg = arg.replace("%", "%%").replace("$", "$$")
    if arg and not re.search(r"[\s\"'\\;]", arg):
        return arg
    return '"%s"' % arg.replace("\\", "\\\\").replace('"', '\\"')


def shell_quote(arg: str) -> str:
    return "'%s'" % arg.replace("'", "'\\''") if re.search(r"[^\w@%+=:,./-]", arg) or not arg else arg


def command(opts: UnitOptions) -> list[str]:
    """ExecStart's command: the launch itself, or (for --setup and --ros-ip-from) bash sourcing the setup and
    reading the address, then exec'ing the launch, so that the launch stays the service's main process."""
    if not opts.setup and not opts.ros_ip_from:
        return list(opts.launch)
    steps = []
    if opts.setup:
        steps.append("source %s" % shell_quote(opts.setup))
    if opts.ros_ip_from:
        # read now, at the service's start (DHCP may give another address at the next boot)
        steps.append("export ROS_IP=\"$(ip -4 -o addr show dev %s scope global | awk '{sub(\"/.*\", \"\", $4); "
                     "print $4; exit}')\"" % shell_quote(opts.ros_ip_from))
        steps.append("{ [ -n \"$ROS_IP\" ] || { echo %s >&2; exit 1; }; }"
                     % shell_quote("no IPv4 address on %s" % opts.ros_ip_from))
    steps.append("exec %s" % " ".join(shell_quote(a) for a in opts.launch))
    return ["/bin/bash", "-c", " && ".join(steps)]


def timeout_stop(opts: UnitOptions) -> int:
    """Seconds systemd waits after SIGINT before it kills what is left: our escalation, then a margin."""
    return int(opts.sigint_timeout + opts.sigterm_timeout + STOP_MARGIN_S + 0.999)


def timeout_start(opts: UnitOptions) -> int:
    """Seconds systemd waits for READY=1: the launch's ready timeout and a margin (its master, its setup)."""
    return max(START_TIMEOUT_S, int(opts.ready_timeout + 0.999) + START_MARGIN_S)


def unit_text(opts: UnitOptions) -> str:
    after = ["network-online.target"] + [a for a in opts.after if a != "network-online.target"]
    lines = [MARK + " (launcher %s); `launcher uninstall %s` removes it." % (__version__, opts.name),
             "# launch files: %s" % " ".join(opts.files),
             "[Unit]",
             "Description=%s" % (opts.description or "ROS launch %s" % " ".join(opts.files)),
             "Wants=network-online.target",
             "After=%s" % " ".join(after),
             # five failed starts in two minutes: systemd gives up (a broken robot does not loop forever)
             "StartLimitIntervalSec=120",
             "StartLimitBurst=5",
             "",
             "[Service]",
             "Type=notify",
             "NotifyAccess=main"]
    if opts.user:
        lines.append("User=%s" % opts.user)  # (with its supplementary groups: dialout, video, audio, plugdev ...)
    env = [("PATH", SYSTEM_PATH), ("PYTHONUNBUFFERED", "1")]
    if opts.ros_home:
        env.append(("ROS_HOME", opts.ros_home))
    if opts.master:
        env.append(("ROS_MASTER_URI", opts.master))
    env += list(opts.env)
    lines += ["Environment=%s" % quote("%s=%s" % kv) for kv in env]
    lines += ["EnvironmentFile=%s" % quote(f) for f in opts.env_files]
    lines += ["ExecStart=%s" % " ".join(quote(a) for a in command(opts)),
              # `systemctl reload`: the launch reads its files again and applies the difference (issue 23); it
              # says RELOADING=1, then READY=1
              "ExecReload=%s reload --launch $MAINPID" % quote(os.path.join(os.path.dirname(opts.launch[0]),
                                                                            "launcher")),
              "KillSignal=SIGINT",
              "KillMode=mixed",
              "TimeoutStartSec=%d" % timeout_start(opts),
              "TimeoutStopSec=%d" % timeout_stop(opts),
              "WatchdogSec=%d" % opts.watchdog_s,
              "Restart=on-failure",
              "RestartSec=2",
              "LogRateLimitIntervalSec=0",
              "",
              "[Install]",
              "WantedBy=%s" % ("multi-user.target" if opts.system else "default.target"),
              ""]
    return "\n".join(lines)


def unit_dir(system: bool, environ: dict[str, str] | None = None) -> str:
    env = os.environ if environ is None else environ
    if system:
        return "/etc/systemd/system"
    config = env.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return os.path.join(config, "systemd", "user")


def launch_executable() -> list[str]:
    """The `launch` of this installation (not whatever a later PATH finds first)."""
    script = os.path.join(os.path.dirname(sys.executable), "launch")
    return [script] if os.access(script, os.X_OK) else [sys.executable, "-m", "launcher"]


class InstallError(Exception):
    pass


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher install", description="write a systemd unit that runs this launch at "
                                "boot (Type=notify, watchdog, restart on failure)")
    p.add_argument("positional", nargs="+", metavar="[pkg] file.launch [name:=value]")
    p.add_argument("--name", help="the unit's name (default: the launch file's)")
    p.add_argument("--description")
    p.add_argument("--run-as", dest="run_as", metavar="USER", help="run as this user (and its groups), with its "
                   "ROS_HOME (a system unit)")
    p.add_argument("--setup", metavar="FILE", help="a workspace's setup.bash, sourced before the launch")
    p.add_argument("--env", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--env-file", dest="env_file", action="append", default=[], metavar="FILE")
    p.add_argument("--ros-ip-from", dest="ros_ip_from", metavar="IFACE", help="ROS_IP is this interface's IPv4 "
                   "address, read when the service starts")
    p.add_argument("--after", action="append", default=[], metavar="UNIT")
    p.add_argument("--wants-network", dest="wants_network", action="store_true",
                   help="(always: the unit wants and comes after network-online.target)")
    p.add_argument("--metrics", metavar="[ADDR:]PORT", help="the launch serves Prometheus metrics there (loopback "
                   "unless an address is given)")
    p.add_argument("--master", metavar="URI", help="use this master (the launch waits for it) instead of the "
                   "launch's own")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--system", action="store_true", default=None, help="a system unit (the default for root)")
    where.add_argument("--user-unit", dest="user_unit", action="store_true", help="a unit of your user's manager")
    p.add_argument("--unit-dir", dest="unit_dir", help="write the unit here (default: /etc/systemd/system, or "
                   "~/.config/systemd/user)")
    p.add_argument("--watchdog-sec", dest="watchdog_sec", type=int, default=DEFAULT_WATCHDOG_S)
    p.add_argument("--sigint-timeout", dest="sigint_timeout", type=float, default=RunOptions().sigint_timeout)
    p.add_argument("--sigterm-timeout", dest="sigterm_timeout", type=float, default=RunOptions().sigterm_timeout)
    p.add_argument("--ready-timeout", dest="ready_timeout", type=float, default=None, metavar="SECONDS",
                   help="the launch's --ready-timeout (READY=1 at the latest after it; TimeoutStartSec= stays above)")
    p.add_argument("--dry-run", dest="dry_run", action="store_true", help="print the unit, write nothing")
    return p


def warn(text: str) -> None:
    print("launcher install: warning: %s" % text, file=sys.stderr)


def options(ns: argparse.Namespace, cwd: str | None = None) -> UnitOptions:
    cwd = cwd or os.getcwd()
    system = not ns.user_unit and (ns.system or os.geteuid() == 0)
    args = [a for a in ns.positional if ":=" in a]
    words = [a for a in ns.positional if ":=" not in a]
    if not words:
        raise InstallError("no launch file given")
    files = [os.path.abspath(os.path.join(cwd, w)) if os.path.exists(os.path.join(cwd, w)) else w for w in words]
    last = os.path.basename(words[-1])
    name = ns.name or (last[:-len(".launch")] if last.endswith(".launch") else last)
    name = name[:-len(".service")] if name.endswith(".service") else name
    if not NAME_OK.fullmatch(name):
        raise InstallError("%r cannot name a unit (letters, digits, ':', '_', '.', '-'): give --name" % name)
    user = ns.run_as or ""
    ros_home = ""
    if user:
        if not system:
            raise InstallError("--run-as is for a system unit (a user unit runs as its user)")
        try:
            ros_home = os.path.join(pwd.getpwnam(user).pw_dir, ".ros")
        except KeyError:
            if not ns.dry_run:
                raise InstallError("no user %r on this machine" % user) from None
            # a dry run writes a unit for another machine (the robot): the user is that machine's
            ros_home = os.path.join("/home", user, ".ros")
            warn("no user %r on this machine: its home taken as /home/%s (ROS_HOME=%s); make sure the machine that "
                 "runs the unit has that user" % (user, user, ros_home))
    env = []
    for item in ns.env:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise InstallError("--env %r: give KEY=VALUE" % item)
        env.append((key, value))
    # --screen: every node's output, INFO included, reaches the journal (and still its <name>-stdout.log)
    if ns.metrics is not None:
        host, _sep, port = ns.metrics.rpartition(":")
        if not port.isdigit() or int(port) > 65535:
            raise InstallError("--metrics: the address is [ADDR:]PORT, not %r" % ns.metrics)
    launch = launch_executable() + files + args + ["--screen"] + (["--wait"] if ns.master else [])
    ready_timeout = RunOptions().ready_timeout
    if ns.ready_timeout is not None:
        if not ns.ready_timeout > 0:
            raise InstallError("--ready-timeout must be greater than zero")
        ready_timeout = ns.ready_timeout
        launch += ["--ready-timeout", "%g" % ready_timeout]
    if ns.metrics is not None:
        launch += ["--metrics", ns.metrics]
    return UnitOptions(name=name, launch=tuple(launch), description=ns.description or "", files=tuple(files),
                       user=user, ros_home=ros_home,
                       setup=os.path.abspath(ns.setup) if ns.setup else "", env=tuple(env),
                       env_files=tuple(os.path.abspath(f) for f in ns.env_file), ros_ip_from=ns.ros_ip_from or "",
                       after=tuple(ns.after), master=ns.master or "", system=system, watchdog_s=ns.watchdog_sec,
                       sigint_timeout=ns.sigint_timeout, sigterm_timeout=ns.sigterm_timeout,
                       ready_timeout=ready_timeout)


def ours(path: str) -> bool:
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().startswith(MARK)
    except OSError:
        return False


def _systemctl(system: bool) -> str:
    return "systemctl" if system else "systemctl --user"


def main(argv: list[str]) -> int:
    ns = _parser().parse_args(argv)
    try:
        opts = options(ns)
    except InstallError as e:
        print("launcher install: %s" % e, file=sys.stderr)
        return 2
    text = unit_text(opts)
    if ns.dry_run:
        sys.stdout.write(text)
        return 0
    directory = ns.unit_dir or unit_dir(opts.system)
    path = os.path.join(directory, opts.name + ".service")
    if os.path.exists(path) and not ours(path):
        print("launcher install: %s exists and was not written by launcher: not replaced (give --name)" % path,
              file=sys.stderr)
        return 1
    try:
        os.makedirs(directory, exist_ok=True)
        with open(path + ".tmp", "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(path + ".tmp", path)
    except OSError as e:
        print("launcher install: cannot write %s: %s" % (path, e.strerror), file=sys.stderr)
        return 1
    ctl = _systemctl(opts.system)
    print("wrote %s\nto start it now and at every boot:\n  %s daemon-reload && %s enable --now %s"
          % (path, ctl, ctl, opts.name))
    return 0


def _where(argv: list[str], prog: str, name: bool) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog=prog)
    if name:
        p.add_argument("name")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--system", action="store_true", default=None)
    where.add_argument("--user-unit", dest="user_unit", action="store_true")
    p.add_argument("--unit-dir", dest="unit_dir")
    return p.parse_args(argv)


def _dirs(ns: argparse.Namespace) -> list[tuple[str, bool]]:
    if ns.unit_dir:
        return [(ns.unit_dir, not ns.user_unit)]
    if ns.system or ns.user_unit:
        return [(unit_dir(not ns.user_unit), not ns.user_unit)]
    return [(unit_dir(True), True), (unit_dir(False), False)]


def uninstall(argv: list[str]) -> int:
    ns = _where(argv, "launcher uninstall", True)
    name = ns.name[:-len(".service")] if ns.name.endswith(".service") else ns.name
    for directory, system in _dirs(ns):
        path = os.path.join(directory, name + ".service")
        if not os.path.exists(path):
            continue
        if not ours(path):
            print("launcher uninstall: %s was not written by launcher: left alone" % path, file=sys.stderr)
            return 1
        ctl = _systemctl(system)
        try:
            os.unlink(path)
        except OSError as e:
            print("launcher uninstall: cannot remove %s: %s" % (path, e.strerror), file=sys.stderr)
            return 1
        print("removed %s\nif it runs or is enabled:\n  %s disable --now %s; %s daemon-reload"
              % (path, ctl, name, ctl))
        return 0
    print("launcher uninstall: no unit %s written by launcher" % name, file=sys.stderr)
    return 1


def installed(argv: list[str]) -> int:
    ns = _where(argv, "launcher installed", False)
    rows = []
    for directory, system in _dirs(ns):
        try:
            names = sorted(os.listdir(directory))
        except OSError:
            continue
        for entry in names:
            path = os.path.join(directory, entry)
            if entry.endswith(".service") and ours(path):
                with open(path, encoding="utf-8") as f:
                    f.readline()
                    files = f.readline().partition(":")[2].strip()
                rows.append((entry[:-len(".service")], system, files))
    for name, system, files in rows:
        print("%s\t%s\t%s\t%s" % (name, "system" if system else "user", state(name, system), files))
    if not rows:
        print("no unit written by `launcher install` in %s" % " or ".join(d for d, _ in _dirs(ns)))
    return 0


def state(name: str, system: bool) -> str:
    """The unit's state as systemd tells it (`systemctl is-active`), or "unknown" without a running systemd."""
    try:
        done = subprocess.run(_systemctl(system).split() + ["is-active", name + ".service"], capture_output=True,
                              text=True, timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return done.stdout.strip() or "unknown"
