"""hang_timeout: a rospy node stopped with SIGSTOP is found hung by its getPid probe, killed and respawned."""

from __future__ import annotations

import asyncio
import os
import signal
import time

import pytest

from launcher.model.config import NodePolicy
from launcher.fleet import state
from launcher.health.hang import HangDetector

from helpers import until_async
from tests.process.health import Events, console_err, supervisor_with_master, talker

pytestmark = pytest.mark.usefixtures("ros_env")

HANG_TIMEOUT = 3.0


def run_hang_scenario(tmp_path, required: bool = False):
    async def main():
        master, sup = await supervisor_with_master()
        hang = HangDetector(sup)
        sup.watchers.append(hang)
        events = Events(sup.fleet)
        try:
            proc = sup.start(talker(tmp_path, "talker", "/chatter", master.uri, respawn=not required,
                                    required=required, policy=NodePolicy(hang_timeout=HANG_TIMEOUT)))
            sup.registrations_complete()
            await until_async(lambda: proc in hang.registered, 30, what="the probe found the registered node")
            first_pid = proc.pid
            os.kill(first_pid, signal.SIGSTOP)
            stopped_at = time.monotonic()
            if required:
                await asyncio.wait_for(sup.done.wait(), HANG_TIMEOUT + 10)
                return sup, events, stopped_at, first_pid
            await until_async(lambda: events.of("/talker", state.HUNG), HANG_TIMEOUT + 10, what="hung")
            await until_async(lambda: proc.alive and proc.pid != first_pid, 10, what="respawned")
            await until_async(lambda: proc in hang.registered, 30, what="the new run registered and probed")
            return sup, events, stopped_at, first_pid
        finally:
            hang.close()
            await sup.shutdown()
            await master.stop()
    return asyncio.run(main())


def test_a_sigstopped_rospy_node_is_found_hung_killed_and_respawned(tmp_path, capsys):
    sup, events, stopped_at, first_pid = run_hang_scenario(tmp_path)
    hung_at = events.of("/talker", state.HUNG)[0][0]
    assert hung_at - stopped_at <= HANG_TIMEOUT + 1.0
    assert hung_at - stopped_at >= HANG_TIMEOUT - HANG_TIMEOUT / 3 - 0.1  # not before it could know
    err = console_err(capsys)
    assert "[talker-1] is hung (no answer to getPid for 3 s): killing process group %d" % first_pid in err
    sequence = [e[2] for e in events.items if e[1] == "/talker"]
    assert sequence[:2] == [state.RUNNING, state.HUNG]
    assert state.RESPAWNING in sequence and sequence.count(state.RUNNING) == 2
    assert sup.fleet.nodes["/talker"].restarts == 1
    with pytest.raises(ProcessLookupError):
        os.kill(first_pid, 0)  # the stopped process was killed, not left behind


def test_a_hung_required_node_ends_the_launch(tmp_path, capsys):
    sup, events, stopped_at, _pid = run_hang_scenario(tmp_path, required=True)
    assert events.of("/talker", state.HUNG)
    assert sup.required_failed
    assert "REQUIRED process [talker-1] has died!" in console_err(capsys)


def test_a_healthy_node_is_not_hung(tmp_path):
    async def main():
        master, sup = await supervisor_with_master()
        hang = HangDetector(sup)
        sup.watchers.append(hang)
        try:
            proc = sup.start(talker(tmp_path, "talker", "/chatter", master.uri, policy=NodePolicy(hang_timeout=0.6)))
            await until_async(lambda: proc in hang.registered, 30)
            since = time.monotonic()
            # ten timeouts' worth of probes, all answered
            await until_async(lambda: time.monotonic() - since > 3.0 or not proc.alive, 10)
            assert proc.alive and sup.fleet.nodes["/talker"].state == state.RUNNING
        finally:
            hang.close()
            await sup.shutdown()
            await master.stop()
    asyncio.run(main())
