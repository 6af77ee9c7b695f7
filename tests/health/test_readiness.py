"""wait_for: a node is held (state `waiting`) until its conditions exist on a real master, or fails to start."""

from __future__ import annotations

import asyncio
import time

import pytest

from launcher.model.config import NodePolicy
from launcher.fleet import state
from launcher.health.readiness import Readiness

from helpers import until_async
from tests.process.health import Events, console_err, python_node, supervisor_with_master, talker

pytestmark = pytest.mark.usefixtures("ros_env")

SLEEPER = "import time\ntime.sleep(100)"


def test_wait_for_holds_a_node_until_a_rospy_publisher_appears(tmp_path):
    async def main():
        master, sup = await supervisor_with_master()
        sup.readiness = Readiness(master.uri, sup, master.graph, sup.fleet)
        events = Events(sup.fleet)
        try:
            policy = NodePolicy(wait_for=(("topic", "/scan"), ("node", "/talker"), ("param", "/robot_description")),
                                wait_timeout=30.0)
            waiter = sup.start(python_node(tmp_path, "waiter", SLEEPER, policy=policy))
            sup.registrations_complete()
            assert sup.fleet.nodes["/waiter"].state == state.WAITING
            assert "topic:/scan, node:/talker, param:/robot_description" in sup.fleet.nodes["/waiter"].reason
            master.set_param("/robot_description", "<robot/>")
            await asyncio.sleep(2.0)  # the publisher really appears 2 s later (the scenario of the issue)
            assert not waiter.alive and sup.fleet.nodes["/waiter"].state == state.WAITING
            sup.start(talker(tmp_path, "talker", "/scan", master.uri))
            await until_async(lambda: waiter.alive, 30, what="the waiting node started")
            return events
        finally:
            sup.readiness.close()
            await sup.shutdown()
            await master.stop()
    events = asyncio.run(main())
    talker_running = events.of("/talker", state.RUNNING)[0][0]
    waiter_running = events.of("/waiter", state.RUNNING)[0][0]
    # rospy needs a while to register; the waiter starts after that, within a poll or two
    assert waiter_running > talker_running + 0.1
    assert [e[2] for e in events.items if e[1] == "/waiter"] == [state.WAITING, state.RUNNING, state.STOPPED]


def test_wait_timeout_names_what_was_missing_and_ends_a_required_node(tmp_path, capsys):
    async def main():
        master, sup = await supervisor_with_master()
        sup.readiness = Readiness(master.uri, sup, master.graph, sup.fleet)
        try:
            master.set_param("/present", 1)
            policy = NodePolicy(wait_for=(("param", "/present"), ("service", "/static_map"), ("topic", "/scan")),
                                wait_timeout=1.0)
            t0 = time.monotonic()
            sup.start(python_node(tmp_path, "optional", SLEEPER, policy=policy))
            sup.start(python_node(tmp_path, "vital", SLEEPER, policy=policy, required=True))
            sup.registrations_complete()
            await asyncio.wait_for(sup.done.wait(), 10)
            return sup, time.monotonic() - t0
        finally:
            sup.readiness.close()
            await sup.shutdown()
            await master.stop()
    sup, waited = asyncio.run(main())
    err = console_err(capsys)
    assert "[optional-1] failed to start: still waiting after 1 s for service:/static_map, topic:/scan" in err
    assert "REQUIRED process [vital-1] failed to start: still waiting after 1 s for service:/static_map" in err
    assert 1.0 <= waited < 5.0
    assert sup.required_failed
    assert sup.fleet.nodes["/optional"].state == state.EXITED
    assert all(p.pid is None for p in sup.procs)  # neither ever ran


def test_a_waiting_node_keeps_an_external_master_launch_going_and_is_stopped_at_shutdown(tmp_path):
    async def main():
        master, sup = await supervisor_with_master()
        sup.fleet.exit_when_all_dead = True  # an external master: the launch ends when every node has ended
        sup.readiness = Readiness(master.uri, sup, master.graph, sup.fleet)
        try:
            sup.start(python_node(tmp_path, "quick", "pass"))
            sup.start(python_node(tmp_path, "held", SLEEPER, policy=NodePolicy(wait_for=(("node", "/never"),))))
            sup.registrations_complete()
            await until_async(lambda: sup.fleet.nodes["/quick"].state == state.EXITED, 10)
            await asyncio.sleep(0.5)
            assert not sup.done.is_set()
        finally:
            sup.readiness.close()
            await sup.shutdown()
            await master.stop()
        return sup
    sup = asyncio.run(main())
    assert sup.fleet.nodes["/held"].state == state.STOPPED
