"""A run's own log: the run's log directory, the launch log, and the summary.

The launch log (`roslaunch-<host>-<pid>.log`) holds every console line and,
beyond roslaunch's, what a user debugging a launch needs: the files, args and
environment it ran with, every parameter, every node's full command line, each
node's state changes with pids, exit codes and signals, and how long each phase
of the start took (`note`). It is a convenience, never a reason to fail: a full
or broken disk makes it a warning (said once) and the run goes on and ends as
it would have.
"""

from __future__ import annotations

import os
import signal
import socket
import time
from typing import Any, Callable, Mapping

from launcher.output import console
from launcher.output.logdir import make_run_log_dir, point_latest
from launcher.fleet.state import Change, visible


class RunLog:
    """`<log root>/<run_id>/` and, in it, `roslaunch-<host>-<pid>.log` with every console line."""

    def __init__(self, environ: Mapping[str, str]):
        self.environ = environ
        self.run_dir = ""
        self.path = ""
        self._file: Any = None

    def open(self, run_id: str) -> str:
        """Make the run's directory, start the launch log and point `latest` at the directory; the directory."""
        self.run_dir = make_run_log_dir(self.environ, run_id)
        self.path = os.path.join(self.run_dir, "roslaunch-%s-%d.log" % (socket.gethostname(), os.getpid()))
        try:
            self._file = open(self.path, "a", buffering=1)
        except OSError:
            self._file = None
        else:
            console.add_handler(self._write)
            console.printlog("... logging to %s" % self.path)
        point_latest(self.run_dir)  # (after that first line: see point_latest)
        return self.run_dir

    def note(self, msg: str) -> None:
        """A line for the launch log only (not the console)."""
        self._write("[launch] " + msg)

    def timing(self, started: float, what: str) -> None:
        """`what` happened, this long after the run started (time.monotonic() then)."""
        self.note("+%.3f s: %s" % (time.monotonic() - started, what))

    def state_change(self, change: Change) -> None:
        """A Fleet listener: each node's state change a reader outside sees, with what a reader of the
        log needs."""
        if not visible(change):
            return
        status = change.status
        text = "node [%s] (process %s) is %s" % (status.name, status.process, status.state)
        if status.pid is not None:
            text += ", pid %s" % status.pid
        if status.exit_signal is not None:
            try:
                text += ", killed by %s" % signal.Signals(status.exit_signal).name
            except ValueError:
                text += ", killed by signal %d" % status.exit_signal
        elif status.exit_code is not None and status.state != "running":
            text += ", exit code %d" % status.exit_code
        if status.registered:
            text += ", registered at %s" % status.uri
        if status.restarts:
            text += ", %d restart%s" % (status.restarts, "" if status.restarts == 1 else "s")
        if status.next_start is not None:
            text += ", next start in %.2f s" % max(0.0, status.next_start - time.time())
        if status.reason:
            text += " (%s)" % status.reason
        self.note(text)

    def _write(self, msg: str) -> None:
        if self._file is None:
            return
        now = time.time()
        try:
            self._file.write("[%s.%03d] %s\n" % (time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(now)),
                                                 int(now * 1000) % 1000, msg))
        except OSError as e:
            self._give_up(e)

    def _give_up(self, error: OSError) -> None:
        """Stop writing the launch log after a write error, and say so once (on the console only)."""
        console.remove_handler(self._write)
        f, self._file = self._file, None
        try:
            f.close()
        except OSError:
            pass  # what was buffered is lost with the disk space
        console.printerrlog("WARNING: cannot write the launch log [%s]: %s; it stops here"
                            % (self.path, error.strerror or error))

    def close(self) -> None:
        if self._file is None:
            return
        console.remove_handler(self._write)
        try:
            self._file.close()
        except OSError as e:
            self._file = None
            console.printerrlog("WARNING: cannot write the launch log [%s]: %s" % (self.path, e.strerror or e))
        self._file = None


def summary(config: Any, params: Mapping[str, Any], remote: Callable[[Any], bool] | None = None,
            machines: bool = False) -> str:
    """roslaunch's SUMMARY block (ROSLaunchConfig.summary).

    As roslaunch: a run that starts nodes on other machines (`machines`) lists the declared
    machines and every node; any other run (no remote nodes, or --local) lists only the nodes of
    this machine (those `remote` does not say are assigned to another one).
    """
    text = "\nSUMMARY\n========"
    if config.clear_params:
        text += "\n\nCLEAR PARAMETERS\n" + "\n".join(sorted(" * %s" % p for p in config.clear_params))
    if params:
        text += "\n\nPARAMETERS\n" + "\n".join(sorted(" * %s: %s" % (k, summary_value(v)) for k, v in params.items()))
    if machines:
        text += "\n\nMACHINES\n" + "\n".join(sorted(" * %s" % m for m in config.machines if m))
    text += "\n\nNODES\n"
    namespaces: dict[str, list[Any]] = {}
    for n in config.nodes:
        if remote is not None and not machines and remote(n):
            continue
        namespaces.setdefault(n.namespace, []).append(n)
    for ns in sorted(namespaces):
        text += "  %s\n" % ns + "\n".join(sorted("    %s (%s/%s)" % (n.name, n.package, n.type)
                                                for n in namespaces[ns]))
        text += "\n"
    return text


def summary_value(value: Any) -> str:
    """roslaunch's strip_string: at most 20 characters, `<...>` for unprintable ones."""
    try:
        value = str(value)
    except Exception:  # noqa: BLE001 - as roslaunch
        return "<...>"
    if len(value) > 20:
        value = value[:17] + "..."
    for i, char in enumerate(value):
        if ord(char) < 32 or ord(char) > 126:
            value = value.rstrip()
            if i >= len(value):
                break
            return "<...>"
    return value
