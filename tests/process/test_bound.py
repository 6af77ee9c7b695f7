"""Bound nodes (bind_to, nodelet loaders) with real processes: stopped while their partner is down, started
once after its next start whatever their own respawn says, left stopped when it is FATAL, and stopped first
when an operator stops it."""

from __future__ import annotations

import asyncio
import os
import signal
import sys

from launcher.fleet import lifecycle
from launcher.model.config import NodePolicy
from launcher.plan.command import NodeCommand
from launcher.plan.relations import of
from launcher.process.supervisor import ProcessSpec, Supervisor

from helpers import pid_alive, until_async

BOUND = NodePolicy(bind_to="/manager", wait_for=(("node", "/manager"),))
# runs until killed; with a file named by argv[1] present, fails at once (a manager that cannot come back)
MANAGER = "import os,sys,time\nif os.path.exists(sys.argv[1]): sys.exit(1)\ntime.sleep(100)"


def spec(tmp_path, name: str, code: str, *args: str, **kw) -> ProcessSpec:
    argv = [sys.executable, "-I", "-S", "-c", code] + list(args)
    return ProcessSpec(name, NodeCommand(argv, dict(os.environ), cwd=str(tmp_path)), node_name="/" + name.split("-")[0],
                       **kw)


def test_a_bound_node_starts_again_once_after_its_respawned_partner(tmp_path):
    async def main():
        sup = Supervisor(exit_when_all_dead=False)
        sup.fleet.relate(of([("/loader", BOUND)]))  # (the plan's: Plan.relations)
        manager = sup.start(spec(tmp_path, "manager-1", MANAGER, str(tmp_path / "broken"), respawn=True,
                                 policy=NodePolicy(respawn_max_retries=2)))
        loader = sup.start(spec(tmp_path, "loader-2", "import time\ntime.sleep(100)", policy=BOUND))
        sup.registrations_complete()
        await until_async(lambda: loader.alive, 10, what="the loader started")
        first_manager, first_loader = manager.pid, loader.pid
        os.kill(first_manager, signal.SIGKILL)
        await until_async(lambda: loader.alive and loader.pid != first_loader, 10, what="the loader started again")
        assert manager.alive and manager.pid != first_manager and not pid_alive(first_loader)
        records = sup.fleet.records
        assert (records["/loader"].spawn_count, records["/manager"].spawn_count) == (2, 2)
        # an operator's stop of the manager stops the loader first; its start brings both back
        await sup.stop_node("/manager")
        assert (records["/loader"].state, records["/manager"].state) == (lifecycle.DETACHED, lifecycle.STOPPED)
        assert not loader.alive
        sup.start_node("/manager")
        await until_async(lambda: loader.alive, 10, what="the loader back with its manager")
        # the manager cannot come back: FATAL, and the loader stays stopped
        (tmp_path / "broken").touch()
        os.kill(manager.pid, signal.SIGKILL)
        await until_async(lambda: records["/manager"].state == lifecycle.FATAL, 20, what="the manager FATAL")
        await until_async(lambda: records["/loader"].state == lifecycle.DETACHED, 10, what="the loader stopped")
        assert not loader.alive and records["/loader"].spawn_count >= 3
        await sup.shutdown()
        return records
    records = asyncio.run(asyncio.wait_for(main(), 60))
    assert records["/loader"].state == lifecycle.STOPPED
