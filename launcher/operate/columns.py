"""A node of a run as text, pure: the columns `launcher status` prints and the live view draws
(operate/view.py), and a change in words as `launcher events` and the view's output pane say it.

Functions of the status's and the change stream's dicts alone (no clock, no I/O): the live view's
state, which is pure, draws its rows with them.
"""

from __future__ import annotations

import signal
from typing import Any

from launcher.fleet.lifecycle import LOCAL_HOST
from launcher.model.units import format_size


def duration(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    s = int(seconds)
    if s < 60:
        return "%ds" % s
    if s < 3600:
        return "%dm%02ds" % (s // 60, s % 60)
    if s < 86400:
        return "%dh%02dm" % (s // 3600, s % 3600 // 60)
    return "%dd%02dh" % (s // 86400, s % 86400 // 3600)


def exit_text(code: int | None, sig: int | None) -> str:
    """How a run ended: SIGSEGV, code 3, or - (not ended)."""
    if sig is not None:
        try:
            return signal.Signals(sig).name
        except ValueError:
            return "signal %d" % sig
    if code is not None:
        return "code %d" % code
    return "-"


def last_exit(node: dict[str, Any]) -> str:
    """The LAST EXIT column: how the node's last run that ended did end, also while it runs again (a status
    from a launch without `last_exit_*`: the current run's exit fields)."""
    if "last_exit_code" in node or "last_exit_signal" in node:
        return exit_text(node.get("last_exit_code"), node.get("last_exit_signal"))
    return exit_text(node.get("exit_code"), node.get("exit_signal"))


# what the table says in place of its rows while a launch sets up (`launcher status`, both views): "no nodes" would
# say the launch has none
STARTING = "starting: its nodes start once the master is up and the parameters are set"
HEADER = ("NODE", "STATE", "REG", "PID", "UPTIME", "RESTARTS", "LAST EXIT", "CPU", "RSS", "HOST")


def registered(n: dict[str, Any]) -> str:
    """The REG column: a running node's run registered with the master ("yes"), or not yet ("no")."""
    if n["state"] not in ("running", "stalled", "hung"):
        return "-"
    return "yes" if n.get("registered") else "no"


def row(n: dict[str, Any]) -> tuple[str, ...]:
    """A node's columns (HEADER), as text: `launcher status` and the live view (operate/view.py) show these."""
    # pid, CPU and RSS are the current run's: a node that is not running has none (the state model
    # keeps the last sample of a run that ended)
    running = n["state"] == "running"
    return (n["name"], n["state"], registered(n), str(n["pid"]) if n.get("pid") and running else "-",
            duration(n.get("uptime")), str(n.get("restarts", 0)), last_exit(n),
            "-" if n.get("cpu") is None or not running else "%.0f%%" % (100 * n["cpu"]),
            "-" if n.get("rss") is None or not running else format_size(n["rss"], measured=True), n.get("host", ""))


def words(event: dict) -> str:
    """A node's change in words, after its name: "running pid 21006 restarts 1 (started by operator)" (the
    live view's output pane says each change so too)."""
    parts = []
    if event.get("host") not in (None, "", LOCAL_HOST):  # a node on another machine (<machine>)
        parts.append("on %s" % event["host"])
    parts.append(event.get("state", "?"))
    if event.get("pid"):
        parts.append("pid %s" % event["pid"])
    if event.get("registered"):  # (its run registered with the master: up, not only running)
        parts.append("registered at %s" % event.get("uri", "?"))
    if event.get("exit_signal") is not None:
        parts.append("signal %s" % event["exit_signal"])
    elif event.get("exit_code") is not None:
        parts.append("exit code %s" % event["exit_code"])
    parts.append("restarts %s" % event.get("restarts", 0))
    if event.get("over_limit"):
        parts.append("over %s" % ", ".join(sorted(event["over_limit"])))
    if event.get("reason"):
        parts.append("(%s)" % event["reason"])
    return " ".join(parts)
