"""The supervisor's restart policy with real child processes: the delay cap, backoff from 0, restart warnings,
deaths by signal under respawn_on="failure", and roslaunch's behaviour (and words) without a policy."""

from __future__ import annotations

import asyncio
import json

from launcher.model.config import NodePolicy
from launcher.output import console
from launcher.fleet import state
from launcher.process.supervisor import Supervisor

from helpers import until_async
from test_supervisor import spec

CRASH = ["/bin/sh", "-c", "exit 1"]


def run_until(tmp_path, specs, cond, timeout=30.0):
    """Run `specs` under a Supervisor writing events to tmp_path until `cond(fleet)`; the events."""
    path = str(tmp_path / "events.jsonl")

    async def main():
        fleet = state.Fleet(path)
        sup = Supervisor(fleet=fleet)
        for s in specs:
            sup.start(s)
        sup.registrations_complete()
        await until_async(lambda: cond(fleet), timeout)
        await sup.shutdown()
        sup.close()
        fleet.close()
    asyncio.run(main())
    console.flush()
    with open(path) as f:
        return [json.loads(line) for line in f]


def delays(evs):
    return [b["time"] - a["time"] for a, b in zip(evs, evs[1:]) if a["state"] == "respawning" and b["state"] == "running"]


def is_fatal(name):
    return lambda fleet: name in fleet.nodes and fleet.nodes[name].state == state.FATAL


def test_delay_grows_up_to_its_cap(tmp_path):
    policy = NodePolicy(respawn_backoff=10, respawn_delay_max=0.3, respawn_max_retries=3)
    evs = run_until(tmp_path, [spec("c-1", CRASH, tmp_path, respawn=True, respawn_delay=0.1, policy=policy)],
                    is_fatal("/c-1"))
    got = delays(evs)
    assert len(got) == 3
    for d, want in zip(got, [0.1, 0.3, 0.3]):  # 0.1, then 1.0 and 10 capped at 0.3
        assert want - 0.02 <= d <= want + 0.3, got


def test_backoff_from_no_delay_starts_at_the_crash_loop_pace(tmp_path):
    policy = NodePolicy(respawn_backoff=2, respawn_max_retries=3)
    evs = run_until(tmp_path, [spec("c-1", CRASH, tmp_path, respawn=True, policy=policy)], is_fatal("/c-1"))
    got = delays(evs)
    assert len(got) == 3
    assert got[0] <= 0.1 + 0.3  # (paced from the start, as without a policy)
    for d, want in zip(got[1:], [0.2, 0.4]):
        assert want - 0.02 <= d <= want + 0.3, got


def test_restart_warn_threshold_warns_once(tmp_path, capsys):
    policy = NodePolicy(restart_warn_threshold=2, respawn_max_retries=4)
    run_until(tmp_path, [spec("c-1", CRASH, tmp_path, respawn=True, policy=policy)], is_fatal("/c-1"))
    err = capsys.readouterr().err
    assert err.count("[c-1] WARNING: restarted 3 times, more than its restart_warn_threshold (2)") == 1
    assert "WARNING: restarted 4 times" not in err


def test_death_by_signal_is_a_failure_for_respawn_on_failure(tmp_path):
    policy = NodePolicy(respawn_on="failure", success_exit_codes=frozenset({0, 9}))
    evs = run_until(tmp_path, [spec("k-1", ["/bin/sh", "-c", "kill -KILL $$"], tmp_path, respawn=True, policy=policy)],
                    lambda fleet: "/k-1" in fleet.nodes and fleet.nodes["/k-1"].restarts >= 2)
    assert [e["exit_signal"] for e in evs if e["state"] == "respawning"][:2] == [9, 9]  # (9 the signal, not a code)


def test_without_a_policy_roslaunch_behaviour_and_words(tmp_path, capsys):
    evs = run_until(tmp_path, [spec("c-1", CRASH, tmp_path, respawn=True)],
                    lambda fleet: "/c-1" in fleet.nodes and fleet.nodes["/c-1"].restarts >= 12)
    out, err = capsys.readouterr()
    # restarted forever at the crash-loop pace, with roslaunch's lines only
    assert out.count("[c-1] restarting process") >= 12
    assert "respawning in" not in out and "FATAL" not in err and "WARNING" not in err
    assert all(0.0 <= d <= 0.1 + 0.3 for d in delays(evs))
    assert "fatal" not in {e["state"] for e in evs}


def test_an_immediate_restart_is_recorded_after_the_respawning(tmp_path):
    # a run longer than the crash-loop pace is restarted at once, inside the exit's handling: its
    # `running` must still follow the `respawning`, and the status must say running
    script = ["/bin/sh", "-c", "sleep 0.3; exit 2"]
    evs = run_until(tmp_path, [spec("s-1", script, tmp_path, respawn=True)],
                    lambda fleet: "/s-1" in fleet.nodes and fleet.nodes["/s-1"].restarts >= 2
                    and fleet.nodes["/s-1"].state == state.RUNNING)
    states = [e["state"] for e in evs]
    assert states[:5] == ["running", "respawning", "running", "respawning", "running"]
