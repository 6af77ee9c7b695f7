"""Which node a registration on our master is: by its name, or by the process that made it (getPid at its URI,
in the node's process group), told to the fleet as the master tells it; a master found running is checked by
the process answering at the URI (an earlier run's registration left behind does not count)."""

from __future__ import annotations

import asyncio
import os

from launcher.fleet import lifecycle as m
from launcher.fleet.lifecycle import Event, Rules
from launcher.fleet.state import Fleet
from launcher.health.registration import Registrations
from launcher.model.config import NodePolicy
from launcher.model.graph import Graph
from launcher.net.slave import SlaveNode
from launcher.net.tcpros import TopicType
from launcher.services.masterlink import start_master

from helpers import until_async

CHAT = TopicType("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1", "string data\n")


def running(fleet: Fleet, name: str, pid: int, rules: Rules = Rules()) -> None:
    fleet.add(name, rules=rules)
    fleet.apply(name, Event(m.START))
    fleet.apply(name, Event(m.SPAWNED, pid=pid))


async def node(name: str, master_uri: str) -> SlaveNode:
    """An in-process node (this process: getPid answers os.getpid(), of the group os.getpgrp()) that registers."""
    n = SlaveNode(name, master_uri, host="127.0.0.1")
    await n.start()
    await n.advertise("/chatter", CHAT)
    return n


def test_a_registration_is_a_nodes_by_its_name_or_by_its_process():
    async def main():
        master = await start_master(0, dict(os.environ))
        fleet = Fleet()
        registrations = Registrations(master.graph, fleet)
        nodes = []
        try:
            # /wrapper's process group is this process's: whatever registers from here is its run
            running(fleet, "/wrapper", os.getpgrp())
            running(fleet, "/talker", 99999999)  # (by name: its process is not asked)
            running(fleet, "/helper", os.getpgrp(), Rules(policy=NodePolicy(registers=False)))
            talker = await node("/talker", master.uri)
            nodes.append(talker)
            assert (fleet.records["/talker"].registered, fleet.records["/talker"].uri) == (True, talker.uri)
            anonymous = await node("/wrapped_4321_1700000000", master.uri)
            nodes.append(anonymous)
            await until_async(lambda: fleet.records["/wrapper"].registered, 10, what="found by its process")
            assert fleet.records["/wrapper"].uri == anonymous.uri
            assert not fleet.records["/helper"].registered  # (it awaits no registration: never looked for)
            # the registrations go with the nodes' own unregistering
            await anonymous.stop()
            await talker.stop()
            nodes.clear()
            assert not fleet.records["/wrapper"].registered and not fleet.records["/talker"].registered
            # a registration no node of the launch waits for is nobody's (and nobody's process is asked)
            fleet.apply("/wrapper", Event(m.PROCESS_EXITED, exit_code=0))
            stranger = await node("/stranger", master.uri)
            nodes.append(stranger)
            await asyncio.sleep(0.3)
            assert not registrations.by_uri and not any(r.registered for r in fleet.records.values())
        finally:
            for n in nodes:
                await n.stop()
            registrations.close()
            await master.stop()
    asyncio.run(main())


def test_on_a_master_found_running_a_registration_by_name_counts_once_its_process_is_the_runs():
    async def main():
        graph = Graph()  # (a watcher's, as services/masterwatch writes it)
        fleet = Fleet()
        registrations = Registrations(graph, fleet, verify=True)
        master = await start_master(0, dict(os.environ))  # (somewhere for the in-process node to register)
        left = await node("/left", master.uri)
        try:
            running(fleet, "/driver", 99999999)  # an earlier run's URI answers with a process not of this run
            graph.node("/driver", left.uri)
            await asyncio.sleep(0.3)
            assert not fleet.records["/driver"].registered
            running(fleet, "/arm", os.getpgrp())  # this run's process answers there
            graph.node("/arm", left.uri)
            await until_async(lambda: fleet.records["/arm"].registered, 10, what="checked by its process")
            graph.node("/arm", None)  # (gone from the master)
            assert not fleet.records["/arm"].registered
        finally:
            await left.stop()
            registrations.close()
            await master.stop()
    asyncio.run(main())


def test_a_burst_of_registrations_on_a_master_found_running_asks_a_few_processes_at_a_time():
    """The watcher's first answer reports a whole start's registrations at once: their getPid calls go
    CALLS_AT_ONCE at a time (a hundred connections at once stayed in the launch's memory), and all are answered."""
    from launcher.health import registration as R
    from launcher.net.xmlrpc import dumps_response

    async def main():
        busy = [0, 0]  # (in flight, most at once)

        async def answer(reader, writer):
            busy[0] += 1
            busy[1] = max(busy)
            head = await reader.readuntil(b"\r\n\r\n")
            length = int([h for h in head.split(b"\r\n") if h.lower().startswith(b"content-length:")][0][15:])
            await reader.readexactly(length)
            await asyncio.sleep(0.02)
            body = dumps_response([1, "", os.getpid()])
            writer.write(b"HTTP/1.1 200 OK\r\nContent-Length: %d\r\n\r\n%s" % (len(body), body))
            await writer.drain()
            busy[0] -= 1
            writer.close()
        server = await asyncio.start_server(answer, "127.0.0.1", 0)
        uri = "http://127.0.0.1:%d/" % server.sockets[0].getsockname()[1]
        graph, fleet = Graph(), Fleet()
        registrations = Registrations(graph, fleet, verify=True)
        try:
            names = ["/n%d" % i for i in range(40)]
            for name in names:
                running(fleet, name, os.getpgrp())
            for name in names:
                graph.node(name, uri)
            await until_async(lambda: all(fleet.records[n].registered for n in names), 20, what="all checked")
            assert busy[1] == R.CALLS_AT_ONCE
        finally:
            registrations.close()
            server.close()
            await server.wait_closed()
    asyncio.run(main())
