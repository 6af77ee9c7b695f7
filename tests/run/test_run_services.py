"""runtime.Run: a run is an ordered list of services, started in order and stopped in reverse; its API server reads a narrow view."""

from __future__ import annotations

import asyncio

from launcher.model.config import LaunchConfig
from launcher.net.xmlrpc import call
from launcher.services.server import LaunchServer
from launcher.model.runopts import RunOptions
from launcher.plan.plan import Plan
from launcher.run.runtime import Run
from launcher.services.servers import RunView

from helpers import free_port, until_async


def _run(tmp_path, body, **kwargs):
    port = free_port()
    env = {"ROS_HOME": str(tmp_path), "ROS_MASTER_URI": "http://127.0.0.1:%d/" % port, "PATH": "/usr/bin:/bin"}
    plan = Plan(LaunchConfig(), "http://127.0.0.1:%d/" % port, env)
    opts = RunOptions(no_summary=True)
    calls: list[str] = []

    async def main() -> int:
        run = Run(opts, plan, **kwargs, body=body)
        for service in run.services:
            stop = service.stop

            async def recorded(stop=stop, name=type(service).__name__) -> None:
                calls.append(name)
                await stop()
            service.stop = recorded
        return await run.main()
    return asyncio.run(main()), calls


def test_a_launch_is_its_services_started_in_order_and_stopped_in_reverse(tmp_path):
    seen = {}

    async def body(run: Run) -> None:
        seen["services"] = [type(s).__name__ for s in run.services]
        seen["up"] = [type(s).__name__ for s in run._up]
        server = run.api.server
        seen["view"] = isinstance(server, LaunchServer) and server.run is run.view and isinstance(run.view, RunView)
        # the server answers from the view: the master and rosout this run started, no node
        seen["processes"] = await call(run.api.uri, "list_processes", timeout=5)
    status, stops = _run(tmp_path, body)
    order = ["MasterSession", "ApiServer", "RosoutService", "NodeService", "DiagnosticsService", "LogDiskCheck"]
    assert status == 0 and seen["services"] == order and sorted(seen["up"]) == sorted(order)
    assert seen["view"] and seen["processes"][2] == [[["master", 1], ["rosout-1", 1]], []]
    assert stops == order[::-1]


def test_a_run_without_the_servers_a_front_end_leaves_out(tmp_path):
    """rostest's choice: no rosout, no /diagnostics, no log-disk check (not a subclass overriding steps)."""
    seen = {}

    async def body(run: Run) -> None:
        seen["processes"] = await call(run.api.uri, "list_processes", timeout=5)
    status, stops = _run(tmp_path, body, rosout=False, diagnostics=False, log_disk=False)
    assert status == 0 and stops == ["NodeService", "ApiServer", "MasterSession"]
    assert seen["processes"][2] == [[["master", 1]], []]


def test_our_master_calls_the_built_in_rosout_in_process_while_it_runs(tmp_path):
    """The publisherUpdate each node's (re)start sends the rosout is a call within the launch, not a request over
    loopback (master/notify.py); the rosout still follows the master's list of /rosout publishers."""
    seen = {}
    publisher = "http://127.0.0.1:1/"  # (nobody there: the rosout's attempts to connect fail, as a dead node's)

    async def body(run: Run) -> None:
        master, rosout = run.master.master, run.rosout.rosout
        seen["apis"] = list(master.in_process_apis)
        seen["rosout"] = rosout.node.uri
        code, _, _ = await call(master.uri, "registerPublisher", "/talker", "/rosout", "rosgraph_msgs/Log",
                                publisher, timeout=5)
        assert code == 1
        subscription = rosout.node.subscriptions["/rosout"]
        await until_async(lambda: publisher in subscription.retries, 10, what="the rosout told of /talker")
        seen["master"] = master
    status, _ = _run(tmp_path, body)
    assert status == 0
    assert seen["apis"] == [seen["rosout"]]
    assert seen["master"].in_process_apis == {}  # (the rosout stopped: gone with it)
