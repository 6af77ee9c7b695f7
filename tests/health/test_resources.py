"""Resource sampling and limits: real processes' CPU and RSS (whole process group) in the Fleet; warn or restart."""

from __future__ import annotations

import asyncio
import json
import os

from launcher.model.config import NodePolicy
from launcher.output import console
from launcher.fleet import state
from launcher.health.resources import GroupReader, ResourceMonitor
from launcher.process.supervisor import Supervisor

from helpers import until_async
from tests.process.health import Events, console_err, python_node

MB = 1 << 20
# allocates (and touches) 80 MB in a child of its own process group: the limit is on the group
GROWER = ("import os, time\n"
          "if os.fork() == 0:\n"
          "    block = b'x' * (80 << 20)\n"
          "    time.sleep(100)\n"
          "time.sleep(100)")
SPINNER = "while True: pass"
IDLE = "import time\ntime.sleep(100)"


def run(tmp_path, specs, until_cond, timeout=20.0, period=0.1):
    async def main():
        sup = Supervisor(sigint_timeout=2.0, sigterm_timeout=1.0)
        events = Events(sup.fleet)
        monitor = ResourceMonitor(sup, period)
        task = asyncio.ensure_future(monitor.run())
        try:
            procs = [sup.start(s) for s in specs]
            seen = await until_async(lambda: until_cond(sup, events), timeout)
            return sup, events, procs, seen
        finally:
            task.cancel()
            await sup.shutdown()
    return asyncio.run(main())


def test_samples_cpu_and_rss_of_the_whole_process_group(tmp_path):
    def grown(sup, events):
        grower, spinner = sup.fleet.nodes["/grower"], sup.fleet.nodes["/spinner"]
        if grower.rss is not None and grower.rss > 80 * MB and len(spinner.history) >= 5:
            return grower.cpu, spinner.cpu, list(spinner.history)
    _sup, _events, _procs, (grower_cpu, spinner_cpu, history) = run(
        tmp_path, [python_node(tmp_path, "grower", GROWER), python_node(tmp_path, "spinner", SPINNER)], grown,
        timeout=40)
    # a busy loop (on a shared, loaded machine: far from always a whole core) against an idle one
    assert max(cpu for _t, cpu, _rss in history) > 0.25
    assert grower_cpu < spinner_cpu
    assert all(cpu >= 0 and rss > 0 for _t, cpu, rss in history)


def test_memory_limit_warns_once_per_crossing(tmp_path, capsys):
    policy = NodePolicy(memory_limit=40 * MB)
    sup, events, procs, _ = run(tmp_path, [python_node(tmp_path, "grower", GROWER, policy=policy)],
                                lambda sup, events: len(sup.fleet.nodes["/grower"].history) >= 8)
    err = console_err(capsys)
    assert err.count("[grower-1] WARNING: uses ") == 1
    assert " of memory, over its limit of 40MiB" in err
    assert procs[0].spawn_count == 1  # warned, not restarted


def test_memory_limit_restart_restarts_the_node(tmp_path, capsys):
    policy = NodePolicy(memory_limit=40 * MB, on_limit="restart")
    sup, events, procs, _ = run(tmp_path, [python_node(tmp_path, "grower", GROWER, policy=policy)],
                                lambda sup, events: len(events.of("/grower", state.RUNNING)) >= 2)
    err = console_err(capsys)
    assert "[grower-1] restarting: uses " in err
    respawning = events.of("/grower", state.RESPAWNING)
    assert respawning and "over its limit of 40MiB" in respawning[0][3]
    assert sup.fleet.nodes["/grower"].restarts >= 1  # though the node does not respawn


def test_cpu_limit_warns(tmp_path, capsys):
    policy = NodePolicy(cpu_limit=0.2)
    run(tmp_path, [python_node(tmp_path, "spinner", SPINNER, policy=policy)],
        lambda sup, events: "[spinner-1] WARNING: uses " in console_err(capsys) or None)


def read_groups(pgids) -> dict:
    """One reading of `pgids` by a GroupReader of its own."""
    reader = GroupReader()
    try:
        return reader.read(pgids)
    finally:
        reader.close()


def test_read_groups_sums_a_group_and_ignores_others(tmp_path):
    async def main():
        sup = Supervisor()
        p = sup.start(python_node(tmp_path, "grower", GROWER))
        q = sup.start(python_node(tmp_path, "idle", IDLE))
        try:
            await until_async(lambda: read_groups({p.pgid}).get(p.pgid, (0, 0))[1] * os.sysconf("SC_PAGE_SIZE") > 80 * MB, 20)
            totals = read_groups({p.pgid, q.pgid})
            assert set(totals) == {p.pgid, q.pgid}
            assert totals[q.pgid][1] * os.sysconf("SC_PAGE_SIZE") < 40 * MB
            assert read_groups({os.getpid() + 10 ** 7}) == {}
        finally:
            await sup.shutdown()
    asyncio.run(main())


# over the limit, back under (the block freed: CPython unmaps large blocks), over again
CYCLER = ("import time\n"
          "for _ in range(2):\n"
          "    block = b'x' * (80 << 20)\n"
          "    time.sleep(1.0)\n"
          "    del block\n"
          "    time.sleep(1.0)\n"
          "time.sleep(100)")


def test_memory_limit_warns_again_after_going_back_under(tmp_path, capsys):
    policy = NodePolicy(memory_limit=40 * MB)
    seen = []

    def two_crossings(sup, events):
        seen.append(console_err(capsys))
        status = sup.fleet.nodes["/cycler"]
        return "".join(seen).count("[cycler-1] WARNING: uses ") >= 2 and status.rss < 40 * MB
    run(tmp_path, [python_node(tmp_path, "cycler", CYCLER, policy=policy)], two_crossings, timeout=30)
    assert "".join(seen).count("[cycler-1] WARNING: uses ") == 2


# holds 80 MB in a child of its group until the file named by its argument exists, then frees it
HOLDER = ("import os, sys, time\n"
          "if os.fork() == 0:\n"
          "    block = bytearray(80 << 20)\n"
          "    for i in range(0, len(block), 4096): block[i] = 1\n"
          "    while not os.path.exists(sys.argv[1]): time.sleep(0.05)\n"
          "    os._exit(0)\n"
          "time.sleep(100)")


def test_over_a_limit_is_in_the_state_model_set_and_cleared(tmp_path, capsys):
    """memory_limit with on_limit="warn": the running node's state says it is over (an event naming the limit),
    back under once it frees the memory (another event), and a new run starts under."""
    release = tmp_path / "release"
    spec = python_node(tmp_path, "holder", HOLDER, policy=NodePolicy(memory_limit=40 * MB), respawn=True)
    spec.command.argv.append(str(release))
    events_path = tmp_path / "events.jsonl"

    async def main():
        sup = Supervisor(sigint_timeout=2.0, sigterm_timeout=1.0, fleet=state.Fleet(str(events_path)))
        task = asyncio.ensure_future(ResourceMonitor(sup, 0.1).run())
        try:
            proc = sup.start(spec)
            status = sup.fleet.nodes["/holder"]
            await until_async(lambda: status.over_limit, 30, what="over memory_limit")
            assert status.state == state.RUNNING and status.over_limit == {"memory_limit": 40 * MB}
            assert status.restarts == 0 and status.pid == proc.pid  # the same run, not a restart
            os.killpg(proc.pgid, 9)  # a new run starts under its limits
            await until_async(lambda: status.restarts == 1 and status.state == state.RUNNING, 30, what="respawned")
            await until_async(lambda: status.over_limit, 30, what="the new run over memory_limit")
            release.touch()
            await until_async(lambda: not status.over_limit, 30, what="back under memory_limit")
            return status.over_limit, status.restarts
        finally:
            task.cancel()
            await sup.shutdown()

    assert asyncio.run(main()) == ({}, 1)
    lines = [json.loads(line) for line in events_path.read_text().splitlines()]
    assert all(e["host"] == "localhost" for e in lines)
    # run 1 over, its death and run 2's start under, run 2 over, then back under
    seen = [(e["state"], e["restarts"], e["over_limit"], e["reason"].split(":")[0]) for e in lines]
    over = {"memory_limit": 40 * MB}
    assert seen[:6] == [("running", 0, {}, ""), ("running", 0, over, "over memory_limit"),
                        ("respawning", 0, {}, ""), ("running", 1, {}, ""), ("running", 1, over, "over memory_limit"),
                        ("running", 1, {}, "back under memory_limit")], seen
    assert " of memory, over its limit of 40MiB" in lines[1]["reason"]
    console.flush()
    said = capsys.readouterr()
    assert said.err.count("[holder-1] WARNING: uses ") == 2
    assert "[holder-1] back under its memory_limit: uses " in said.out
