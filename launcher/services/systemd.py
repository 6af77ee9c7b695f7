"""systemd's notify protocol for `launch` run as a service: READY=1, STATUS=, WATCHDOG=1, STOPPING=1 to $NOTIFY_SOCKET.

The protocol is one datagram of `KEY=value` lines to the AF_UNIX socket named
by `NOTIFY_SOCKET` (a leading `@` is the abstract namespace), so it is spoken
here directly. The words (`message`, `fleet_status`, `not_ready`) are pure
functions of the fleet; `Notifier` sends them from the launch's loop:

- READY=1 once every node meant to start has started and registered with the
  master (the fleet's records say so: `health/registration.py` tells them as the
  master does; a node with `registers="false"` counts once it runs), or when
  `--ready-timeout` (60 s) passes (then STATUS= names the nodes not up), so that
  systemd's "active" means the robot is up;
- STATUS= after every change of the fleet ("12/12 nodes running, 1 respawning");
- WATCHDOG=1 every half of WATCHDOG_USEC from a loop timer: a loop that is stuck
  sends nothing, and systemd restarts the launch (WatchdogSec=);
- STOPPING=1 when the launch begins its orderly stop.

Without NOTIFY_SOCKET nothing of this runs (`Notifier.from_environ` is None).
"""

from __future__ import annotations

import asyncio
import os
import socket
import time
from typing import TYPE_CHECKING, Any, Callable, Iterable

from launcher.fleet import lifecycle
from launcher.model.runopts import RunOptions

if TYPE_CHECKING:  # (annotations only)
    from launcher.fleet.state import Change, Fleet

# How long READY=1 waits for the nodes before it is sent anyway, naming the nodes not up (systemd's own
# TimeoutStartSec, which the unit sets longer, would otherwise kill a robot with one node that is slow)
READY_TIMEOUT_S = RunOptions().ready_timeout
# on the way up: a node in one of these is not started yet
NOT_STARTED = frozenset((lifecycle.NEW, lifecycle.DELAYED, lifecycle.HELD)) | lifecycle.ON_THE_WAY


def message(**fields: Any) -> bytes:
    """One notification: `message(READY=1, STATUS="3/3 nodes running")` -> b"READY=1\\nSTATUS=3/3 nodes running".

    A value cannot hold a newline (it would end the field): it is made a space."""
    return "\n".join("%s=%s" % (k, str(v).replace("\n", " ")) for k, v in fields.items()).encode()


def socket_address(value: str) -> str | bytes:
    """The address of $NOTIFY_SOCKET: a path, or `@name`, a name in the abstract namespace."""
    if value.startswith("@"):
        return b"\0" + value[1:].encode()
    return value


def watchdog_period(environ: dict[str, str], pid: int) -> float | None:
    """Seconds between WATCHDOG=1 pings (half of WATCHDOG_USEC, as sd_watchdog_enabled advises), or None
    when systemd asks for none or asks another process (WATCHDOG_PID)."""
    usec = environ.get("WATCHDOG_USEC", "")
    wpid = environ.get("WATCHDOG_PID", "")
    if not usec.isdigit() or int(usec) == 0 or (wpid and wpid != str(pid)):
        return None
    return int(usec) / 2e6


def fleet_status(records: Iterable[lifecycle.Record]) -> str:
    """The STATUS= line: "12/12 nodes running, 1 respawning" (the other states counted when there are any)."""
    counts: dict[str, int] = {}
    total = 0
    for r in records:
        total += 1
        public = lifecycle.PUBLIC[r.state]
        counts[public] = counts.get(public, 0) + 1
    text = "%d/%d nodes running" % (counts.pop("running", 0), total)
    return ", ".join([text] + ["%d %s" % (n, state) for state, n in sorted(counts.items())])


def not_ready(records: Iterable[lifecycle.Record]) -> list[str]:
    """The nodes that keep the launch from being ready: not started yet, or running but not registered with
    the master (unless `registers="false"` says it never will). A node that ended (or was kept stopped) is
    no longer awaited: it is named in STATUS= instead."""
    waiting = []
    for r in records:
        if r.state in NOT_STARTED and not r.operator_stopped:
            waiting.append(r.name)
        elif r.state == lifecycle.RUNNING and not r.registered and r.rules.policy.registers:
            waiting.append(r.name)
    return waiting


class Notifier:
    """The launch's messages to its service manager, sent from the loop."""

    def __init__(self, address: str | bytes, watchdog_s: float | None, *, warn: Callable[[str], None] = print,
                 ready_timeout: float = READY_TIMEOUT_S):
        self.address = address
        self.watchdog_s = watchdog_s
        self.ready_timeout = ready_timeout
        self.ready = False
        self._warn = warn
        self._warned = False
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._fleet: Fleet | None = None
        self._status = ""
        self._status_due = False
        self._ping: asyncio.TimerHandle | None = None
        self._deadline: asyncio.TimerHandle | None = None  # the ready timeout, while not ready
        self._stopping = False
        self._queued: list[bytes] = []  # messages the socket could not take yet, oldest first
        self._waiting_writable = False

    @classmethod
    def from_environ(cls, environ: dict[str, str] | None = None, **kw: Any) -> Notifier | None:
        env = os.environ if environ is None else environ
        value = env.get("NOTIFY_SOCKET", "")
        if not value:
            return None
        return cls(socket_address(value), watchdog_period(dict(env), os.getpid()), **kw)

    def send(self, data: bytes) -> None:
        """Send one message, in order after any that wait. A full socket (the manager busy, as systemd is at
        boot) keeps it for when the socket can take it: READY=1 lost there would have systemd kill the launch
        at TimeoutStartSec (sd_notify blocks instead; the launch's loop must not)."""
        self._queued.append(data)
        if len(self._queued) == 1:
            self._flush()

    def _flush(self) -> None:
        while self._queued:
            try:
                self._sock.sendto(self._queued[0], self.address)
            except BlockingIOError:
                if not self._waiting_writable:
                    self._waiting_writable = True
                    asyncio.get_running_loop().add_writer(self._sock.fileno(), self._flush)
                return
            except OSError as e:  # the service manager gone: the robot runs on, said once
                if not self._warned:
                    self._warned = True
                    self._warn("cannot notify the service manager at %r: %s" % (self.address, e.strerror or e))
            del self._queued[0]
        if self._waiting_writable:
            self._waiting_writable = False
            asyncio.get_running_loop().remove_writer(self._sock.fileno())

    # ---- the watchdog: pings from the loop itself, so a stuck loop sends none --------------------------------

    def start_watchdog(self) -> None:
        if self.watchdog_s is not None and self._ping is None:
            self._watchdog()

    def _watchdog(self) -> None:
        self.send(message(WATCHDOG=1))
        self._ping = asyncio.get_running_loop().call_later(self.watchdog_s, self._watchdog)

    # ---- readiness and status -------------------------------------------------------------------------------

    def attach(self, fleet: Fleet) -> None:
        """Follow `fleet`: STATUS= at its changes, READY=1 once its nodes are up (each change is looked at:
        a registration is one), at the latest after the ready timeout."""
        self._fleet = fleet
        fleet.listeners.append(self._changed)
        self._deadline = asyncio.get_running_loop().call_later(self.ready_timeout, self._timed_out)
        self._check_ready()

    def _changed(self, change: Change) -> None:
        if not self.ready:
            self._check_ready()
        if not self._status_due:  # (a burst of changes in one loop pass makes one datagram)
            self._status_due = True
            asyncio.get_running_loop().call_soon(self._send_status)

    def _send_status(self, **more: Any) -> None:
        self._status_due = False
        status = fleet_status(self._fleet.records.values())
        if status != self._status or more:
            self._status = status
            self.send(message(**more, STATUS=status))

    def _check_ready(self) -> None:
        if self.ready or self._stopping or self._fleet is None or not_ready(self._fleet.records.values()):
            return
        self._ready()
        self._send_status(READY=1)

    def _ready(self) -> None:
        self.ready = True
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _timed_out(self) -> None:
        self._deadline = None
        if self.ready or self._stopping:
            return
        waiting = not_ready(self._fleet.records.values())
        self._ready()
        if not waiting:
            self._send_status(READY=1)
            return
        self._status = ""
        self.send(message(READY=1, STATUS="%s; not up after %gs: %s" % (
            fleet_status(self._fleet.records.values()), self.ready_timeout, ", ".join(waiting))))

    # ---- a reload ---------------------------------------------------------------------------------------------

    def reloading(self) -> None:
        """A reload begins (`launcher reload`, or systemctl reload through the unit's ExecReload=)."""
        self.send(message(RELOADING=1, MONOTONIC_USEC=time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000,
                          STATUS="reloading"))

    def reloaded(self) -> None:
        """The reload is applied: READY=1 again (once the launch was ready before), with the fleet's status."""
        if self._fleet is None or not self.ready:
            self.send(message(STATUS="reloaded"))
            return
        self._status = ""
        self._send_status(READY=1)

    # ---- the end --------------------------------------------------------------------------------------------

    def stopping(self) -> None:
        """The orderly stop begins (the watchdog keeps pinging: the stop escalation runs on the loop)."""
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        self._stopping = True  # (no READY=1 after STOPPING=1: the nodes going down are no launch coming up)
        self.send(message(STOPPING=1, STATUS="stopping"))

    def close(self) -> None:
        if self._ping is not None:
            self._ping.cancel()
        if self._deadline is not None:
            self._deadline.cancel()
        if self._waiting_writable:
            self._waiting_writable = False
            asyncio.get_running_loop().remove_writer(self._sock.fileno())
        if self._queued:  # (the last words, STOPPING=1 among them: a second for the manager to take them)
            self._sock.settimeout(1.0)
            for data in self._queued:
                try:
                    self._sock.sendto(data, self.address)
                except OSError:
                    break
            self._queued.clear()
        self._sock.close()
