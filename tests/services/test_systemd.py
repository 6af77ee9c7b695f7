"""The notify protocol's words: the datagram, the socket's address, the watchdog period, STATUS= and readiness."""

from __future__ import annotations

import asyncio
import socket

from helpers import until_async
from launcher.model.config import NodePolicy
from launcher.services import systemd
from launcher.fleet import lifecycle


def rec(name: str, state: str, started: float | None = None, min_uptime: float = 1.0, **kw) -> lifecycle.Record:
    rules = lifecycle.Rules(policy=NodePolicy(respawn_min_uptime=min_uptime))
    return lifecycle.Record(name, name.strip("/"), "localhost", rules, state=state, started=started, **kw)


def test_message_is_key_value_lines():
    assert systemd.message(READY=1, STATUS="2/2 nodes running") == b"READY=1\nSTATUS=2/2 nodes running"
    assert systemd.message(STATUS="a\nb") == b"STATUS=a b"


def test_abstract_socket_address():
    assert systemd.socket_address("/run/systemd/notify") == "/run/systemd/notify"
    assert systemd.socket_address("@sd/notify") == b"\0sd/notify"


def test_watchdog_period_is_half_of_watchdog_usec_for_this_pid_only():
    assert systemd.watchdog_period({"WATCHDOG_USEC": "20000000"}, 7) == 10.0
    assert systemd.watchdog_period({"WATCHDOG_USEC": "20000000", "WATCHDOG_PID": "7"}, 7) == 10.0
    assert systemd.watchdog_period({"WATCHDOG_USEC": "20000000", "WATCHDOG_PID": "8"}, 7) is None
    assert systemd.watchdog_period({}, 7) is None
    assert systemd.watchdog_period({"WATCHDOG_USEC": "0"}, 7) is None


def test_status_counts_the_public_states():
    records = [rec("/a", lifecycle.RUNNING), rec("/b", lifecycle.STOPPING), rec("/c", lifecycle.RESPAWNING),
               rec("/d", lifecycle.FATAL), rec("/e", lifecycle.STARTING)]
    assert systemd.fleet_status(records) == "2/5 nodes running, 1 fatal, 1 respawning, 1 waiting"
    assert systemd.fleet_status([]) == "0/0 nodes running"


def test_not_ready_until_started_and_registered_unless_it_never_registers():
    helper = lifecycle.Rules(policy=NodePolicy(registers=False))
    records = [rec("/starting", lifecycle.STARTING), rec("/held", lifecycle.HELD),
               rec("/young", lifecycle.RUNNING, started=99.5),
               rec("/registered", lifecycle.RUNNING, started=10.0, registered=True, uri="http://h:1/"),
               rec("/old", lifecycle.RUNNING, started=1.0), rec("/dead", lifecycle.FATAL),
               rec("/kept", lifecycle.NEW, operator_stopped=True), rec("/respawning", lifecycle.RESPAWNING),
               lifecycle.Record("/helper", "helper", "localhost", helper, state=lifecycle.RUNNING, started=99.9)]
    # (a node up for a long time but not registered is awaited all the same: only its registration says up)
    assert systemd.not_ready(records) == ["/starting", "/held", "/young", "/old"]
    assert systemd.not_ready([rec("/a", lifecycle.RUNNING, registered=True), records[-1]]) == []


def test_a_full_socket_keeps_the_messages_in_order_until_it_takes_them(tmp_path):
    # the service manager's end, filled until it takes no more (as systemd busy at boot)
    path = str(tmp_path / "notify")
    manager = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    manager.bind(path)
    manager.setblocking(False)
    fillers: list[socket.socket] = []  # (a sender's own buffer fills too: a new sender each time it does)
    filled = 0
    while True:
        fillers.append(socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM))
        fillers[-1].setblocking(False)
        sent = 0
        while True:
            try:
                fillers[-1].sendto(b"X=%d" % filled, path)
            except BlockingIOError:
                break
            filled += 1
            sent += 1
        if sent == 0:  # a fresh sender refused at once: the manager's queue is full
            break
    warnings: list[str] = []

    def received() -> list[bytes]:
        out = []
        while True:
            try:
                out.append(manager.recv(4096))
            except BlockingIOError:
                return out

    async def main() -> list[bytes]:
        notifier = systemd.Notifier(path, None, warn=warnings.append)
        notifier.send(systemd.message(STATUS="1/2 nodes running"))
        notifier.send(systemd.message(READY=1, STATUS="2/2 nodes running"))
        notifier.send(systemd.message(STATUS="stopping"))
        await asyncio.sleep(0.05)
        got = received()  # (makes room: the three follow once the loop sees the socket writable)
        await until_async(lambda: len(got) >= filled + 3 or got.extend(received()), 5, what="the kept messages")
        notifier.close()
        return got

    got = asyncio.run(main())
    assert got[:filled] == [b"X=%d" % i for i in range(filled)]
    assert got[filled:] == [b"STATUS=1/2 nodes running", b"READY=1\nSTATUS=2/2 nodes running", b"STATUS=stopping"]
    assert warnings == []
    manager.close()
    for filler in fillers:
        filler.close()
