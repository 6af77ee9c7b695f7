"""`/diagnostics`: every node's state as a diagnostic_msgs/DiagnosticArray, once a second (`--no-diagnostics`: off).

One DiagnosticStatus per node, named after the node (and, with our master, one
named MASTER_STATUS while some registered node does not answer its callbacks:
WARN, a value per node saying for how long and why): OK while it runs,
WARN while it is over a limit (memory_limit, cpu_limit), respawns or is
stopped, ERROR when it is fatal, hung, or exited with a failure. rqt_robot_monitor and `rostopic echo /diagnostics`
show the fleet. The message definition and md5sum are rosbags' (kept as
constants, checked against rosbags by the tests); the message is serialized
here, which for 500 nodes is a fraction of what building rosbags' message
objects would cost each second. Nothing is built while nobody subscribes.
"""

from __future__ import annotations

import asyncio
import struct
import time
from typing import TYPE_CHECKING, Any, Iterable, Mapping

from launcher import compat
from launcher.fleet import state

if TYPE_CHECKING:  # (annotations only)
    from launcher.master.server import Master

TOPIC = "/diagnostics"
TYPE = "diagnostic_msgs/DiagnosticArray"
PERIOD_S = 1.0
NODE_NAME = "/launcher_diagnostics"
MASTER_STATUS = "/launcher/master"

OK, WARN, ERROR, STALE = 0, 1, 2, 3

_U32 = struct.Struct("<I")


def level_of(status: Any) -> tuple[int, str]:
    """(level, message) of one node's state."""
    s = status.state
    if s == state.RUNNING:
        if status.over_limit:
            return WARN, "running, over " + state.over_limit_text(status.over_limit, status.cpu, status.rss)
        return OK, "running"
    if s == state.RESPAWNING:
        return WARN, "respawning"
    if s in (state.FATAL, state.HUNG):
        return ERROR, s
    if s == state.STALLED:
        return ERROR, "stalled: " + status.reason
    if s == state.EXITED:
        if status.exit_signal is not None:
            return ERROR, "exited by signal %d" % status.exit_signal
        if status.exit_code:
            return ERROR, "exited with code %d" % status.exit_code
        return OK, "exited cleanly"
    if s == state.STOPPED:
        return WARN, "stopped"
    return OK, s  # waiting


def _string(out: list[bytes], text: str) -> None:
    data = text.encode("utf-8", "replace")
    out.append(_U32.pack(len(data)))
    out.append(data)


def _values(status: Any, now: float) -> list[tuple[str, str]]:
    uptime = status.uptime(now)
    values = [("state", status.state), ("pid", "" if status.pid is None else str(status.pid)),
              ("restarts", str(status.restarts)), ("uptime", "" if uptime is None else "%.1f" % uptime)]
    if status.exit_code is not None:
        values.append(("exit_code", str(status.exit_code)))
    if status.exit_signal is not None:
        values.append(("exit_signal", str(status.exit_signal)))
    if status.cpu is not None:
        values.append(("cpu", "%.3f" % status.cpu))
    if status.rss is not None:
        values.append(("rss", str(status.rss)))
    for limit, maximum in sorted(status.over_limit.items()):
        values.append((limit, str(maximum)))  # (bytes or cores, as the launch file gave them)
    if status.reason:
        values.append(("reason", status.reason))
    return values


def unresponsive_text(u: Any) -> str:
    """One node the master cannot reach, in words (status and /diagnostics)."""
    return "%s: %d failed callback%s over %.0f s (%s), %d waiting" % (
        " ".join(u.names) or u.api, u.failures, "" if u.failures == 1 else "s", u.failing_s, u.last_error, u.queued)


def master_status(unresponsive: list[Any]) -> tuple[int, str, str, str, list[tuple[str, str]]] | None:
    """The master's status entry: None while every registered node answers its callbacks."""
    if not unresponsive:
        return None
    return (WARN, MASTER_STATUS, "%d node(s) do not answer the master's callbacks" % len(unresponsive), "localhost",
            [(u.api, unresponsive_text(u)) for u in unresponsive])


def serialize(nodes: Iterable[Any], seq: int, now: float, extra: Iterable[tuple] = ()) -> bytes:
    """A DiagnosticArray of the nodes' states (and `extra` entries: level, name, message, hardware id,
    values), in ROS 1 wire format."""
    entries = [(*level_of(s), s.name, s.host, _values(s, now)) for s in nodes]
    entries = [(level, name, message, host, values) for level, message, name, host, values in entries]
    entries += list(extra)
    secs = int(now)
    out = [struct.pack("<III", seq, secs, int((now - secs) * 1e9)), _U32.pack(0), _U32.pack(len(entries))]
    for level, name, message, host, values in entries:
        out.append(struct.pack("<b", level))
        _string(out, name)
        _string(out, message)
        _string(out, host)
        out.append(_U32.pack(len(values)))
        for key, value in values:
            _string(out, key)
            _string(out, value)
    return b"".join(out)


# diagnostic_msgs/DiagnosticArray as rosbags' ROS1_NOETIC store gives it (tests/services/test_diagnostics.py
# checks): constants, because loading that store costs ~100 ms of CPU, taken from the launch as it starts.
MD5 = "60810da900de1dd6ddd437c3503511da"
_SEP = "=" * 80 + "\n"
DEFINITION = (
    "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n"
    + _SEP + "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
    + _SEP + "MSG: diagnostic_msgs/DiagnosticStatus\nbyte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\n"
    "byte level\nstring name\nstring message\nstring hardware_id\ndiagnostic_msgs/KeyValue[] values\n"
    + _SEP + "MSG: diagnostic_msgs/KeyValue\nstring key\nstring value\n")


def topic_type() -> Any:
    from launcher.net.tcpros import TopicType
    return TopicType(TYPE, MD5, DEFINITION)


class Diagnostics:
    """A node of the launcher that publishes the fleet's states on /diagnostics."""

    def __init__(self, master_uri: str, fleet: state.Fleet, *, environ: Mapping[str, str] | None = None,
                 period: float = PERIOD_S, master: Master | None = None):
        self.master_uri = master_uri
        self.fleet = fleet
        self.master = master  # our master (None: a master found running), for the nodes it cannot reach
        self.environ = environ
        self.period = period
        self.node: Any = None
        self.publication: Any = None
        self.seq = 0
        self._task: asyncio.Task | None = None

    async def start(self) -> None:
        from launcher.net.slave import SlaveNode, default_host
        mtype = topic_type()
        self.node = SlaveNode(NODE_NAME, self.master_uri, host=default_host(self.environ))
        await self.node.start()
        try:
            self.publication = await self.node.advertise(TOPIC, mtype)
        except BaseException:
            await self.node.stop()
            raise
        self._task = asyncio.get_running_loop().create_task(self._publish_every_period())

    async def _publish_every_period(self) -> None:
        while True:
            self.publish_once()
            await asyncio.sleep(self.period)

    def publish_once(self) -> None:
        pub = self.publication
        self.seq += 1
        if pub is None or not pub.links or self.fleet is None:
            return  # nobody listens: build nothing
        entry = master_status(self.master.unresponsive_nodes()) if self.master is not None else None
        pub.publish(serialize(self.fleet, self.seq, time.time(), [entry] if entry else []))

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
        if self.node is not None:
            try:
                await compat.wait_for(self.node.stop(), 5.0)
            except (Exception, asyncio.TimeoutError):  # noqa: BLE001 - shutting down: the master may be gone
                pass
            self.node = None
