"""The supervisor with real child processes: spawn, exit reports, respawn, required, stop escalation."""

from __future__ import annotations

import asyncio
import os
import signal
import sys
import time

import pytest

from launcher.plan.command import NodeCommand
from launcher.process.supervisor import MIN_RESPAWN_INTERVAL_S, ProcessSpec, Supervisor

from helpers import pid_alive, until_async

PY = sys.executable


def py_node(code: str) -> list[str]:
    return [PY, "-I", "-S", "-c", code]


def spec(name: str, argv: list[str], tmp_path, **kw) -> ProcessSpec:
    return ProcessSpec(name, NodeCommand(argv, dict(os.environ), cwd=str(tmp_path)), **kw)


IGNORE_INT = "import signal,time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nprint('ready', flush=True)\ntime.sleep(100)"
IGNORE_BOTH = ("import signal,time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\n"
               "signal.signal(signal.SIGTERM, signal.SIG_IGN)\nprint('ready', flush=True)\ntime.sleep(100)")


def test_exit_reports_and_all_dead(tmp_path, capsys):
    async def main():
        sup = Supervisor()
        sup.start(spec("ok-1", ["/bin/sh", "-c", "exit 0"], tmp_path))
        sup.start(spec("bad-2", ["/bin/sh", "-c", "exit 3"], tmp_path, log_dir=str(tmp_path)))
        sup.registrations_complete()
        await asyncio.wait_for(sup.done.wait(), 10)
        await sup.shutdown()
        return sup
    sup = asyncio.run(main())
    out, err = capsys.readouterr()
    assert "process[ok-1]: started with pid [" in out
    assert "[ok-1] process has finished cleanly" in out
    pid = sup.procs[1].pid
    assert "[bad-2] process has died [pid %d, exit code 3, cmd /bin/sh -c exit 3].\nlog file: %s*.log" % (
        pid, os.path.join(str(tmp_path), "bad-2")) in err
    assert "all processes on machine have died, roslaunch will exit" in out
    assert not sup.required_failed


def test_signal_death_reports_negative_code(tmp_path, capsys):
    async def main():
        sup = Supervisor()
        p = sup.start(spec("victim-1", ["sleep", "100"], tmp_path))
        sup.registrations_complete()
        os.kill(p.pid, signal.SIGKILL)
        await asyncio.wait_for(sup.done.wait(), 10)
        return p
    p = asyncio.run(main())
    assert "[victim-1] process has died [pid %d, exit code -9, cmd sleep 100]" % p.pid in capsys.readouterr().err


def test_no_exit_while_core_runs(tmp_path):
    """With our own master (exit_when_all_dead=False) the launch keeps running when nodes finish, as roslaunch."""
    async def main():
        sup = Supervisor(exit_when_all_dead=False)
        p = sup.start(spec("ok-1", ["/bin/true"], tmp_path))
        sup.registrations_complete()
        await until_async(lambda: not p.alive, 10)  # (the exit is handled in one callback: done would be set now)
        return sup.done.is_set()
    assert asyncio.run(main()) is False


def test_missing_executable_reported_and_rest_carry_on(tmp_path, capsys):
    async def main():
        sup = Supervisor()
        bad = sup.start(spec("ghost-1", [str(tmp_path / "nope")], tmp_path))
        good = sup.start(spec("alive-2", ["sleep", "100"], tmp_path))
        sup.registrations_complete()
        alive = good.alive and pid_alive(good.pid)
        await sup.shutdown()
        return bad, good, alive, sup
    bad, good, alive, sup = asyncio.run(main())
    err = capsys.readouterr().err
    assert bad is None and alive
    assert "[ghost-1] got a 'No such file or directory' error while attempting to run" in err
    assert "bad launch-prefix" in err
    assert not sup.required_failed
    assert not pid_alive(good.pid)


def test_required_missing_executable_ends_launch_with_failure(tmp_path, capsys):
    async def main():
        sup = Supervisor()
        sup.start(spec("need-1", [str(tmp_path / "nope")], tmp_path, required=True))
        return sup
    sup = asyncio.run(main())
    assert sup.required_failed and sup.done.is_set()
    assert "REQUIRED process [need-1] could not be started!" in capsys.readouterr().err


@pytest.mark.parametrize("code,failed", [(0, False), (4, True)])
def test_required_exit_ends_launch(tmp_path, capsys, code, failed):
    async def main():
        sup = Supervisor(exit_when_all_dead=False)
        other = sup.start(spec("other-1", ["sleep", "100"], tmp_path))
        sup.start(spec("req-2", ["/bin/sh", "-c", "sleep 0.1; exit %d" % code], tmp_path, required=True))
        sup.registrations_complete()
        await asyncio.wait_for(sup.done.wait(), 10)
        await sup.shutdown()
        return sup, other
    sup, other = asyncio.run(main())
    err = capsys.readouterr().err
    assert "REQUIRED process [req-2] has died!" in err and "Initiating shutdown!" in err
    assert sup.required_failed is failed
    assert not pid_alive(other.pid)


def test_respawn_immediately_and_with_delay(tmp_path, capsys):
    async def main():
        sup = Supervisor()
        fast = sup.start(spec("fast-1", ["sleep", "100"], tmp_path, respawn=True))
        slow = sup.start(spec("slow-2", ["sleep", "100"], tmp_path, respawn=True, respawn_delay=0.6))
        sup.registrations_complete()
        lat = []
        for _ in range(5):
            # a node that ran a while (a crash loop is paced: see below)
            await until_async(lambda: asyncio.get_running_loop().time() - sup.fleet.records[fast.spec.node_name].started
                              > MIN_RESPAWN_INTERVAL_S, 10)
            old = fast.pid
            t0 = time.monotonic()
            os.kill(old, signal.SIGKILL)
            await until_async(lambda: fast.pid != old and fast.alive, 10, period=0.0005)
            lat.append(time.monotonic() - t0)
        old = slow.pid
        t0 = time.monotonic()
        os.kill(old, signal.SIGKILL)
        await until_async(lambda: slow.pid != old and slow.alive, 10)
        slow_delay = time.monotonic() - t0
        fast_pid, slow_pid = fast.pid, slow.pid
        await sup.shutdown()
        return sorted(lat), slow_delay, fast.spawn_count, sup.done.is_set(), fast_pid, slow_pid
    lat, slow_delay, count, done, fast_pid, slow_pid = asyncio.run(main())
    assert count == 6
    assert lat[2] < 0.1, lat  # median: an exit is noticed when it happens, not at a poll tick
    assert 0.6 <= slow_delay < 2.0
    assert not done  # respawning nodes never count as "all dead"
    out = capsys.readouterr().out
    assert out.count("[fast-1] restarting process") == 5
    assert out.count("process[fast-1]: started with pid [") == 6
    assert not pid_alive(fast_pid) and not pid_alive(slow_pid)


def test_log_output_file_truncated_or_appended(tmp_path):
    log = tmp_path / "n-1-stdout.log"
    log.write_text("old\n")

    async def main(respawn):
        sup = Supervisor()
        p = sup.start(spec("n-1", ["/bin/sh", "-c", "echo run $$"], tmp_path, stdout_path=str(log), respawn=respawn))
        if respawn:
            await until_async(lambda: p.spawn_count >= 4, 10)
        else:
            await until_async(lambda: not p.alive, 10)
        await sup.shutdown()
    asyncio.run(main(False))
    assert log.read_text().startswith("run ") and log.read_text().count("run ") == 1
    asyncio.run(main(True))
    assert log.read_text().count("run ") >= 3  # respawn appends, as roslaunch's mode 'a'


def test_cwd_and_env(tmp_path):
    out = tmp_path / "out.txt"
    work = tmp_path / "work"

    async def main():
        sup = Supervisor()
        env = {"PATH": os.environ["PATH"], "MY_VAR": "hello"}
        p = sup.start(ProcessSpec("e-1", NodeCommand(["/bin/sh", "-c", "pwd > %s; echo $MY_VAR >> %s" % (out, out)],
                                                     env, cwd=str(work))))
        await until_async(lambda: not p.alive, 10)
        await sup.shutdown()
    asyncio.run(main())
    assert out.read_text().split() == [str(work), "hello"]


def test_stop_escalation_sigint_sigterm_sigkill(tmp_path, capsys):
    async def main():
        sup = Supervisor(sigint_timeout=0.4, sigterm_timeout=0.3)
        polite = sup.start(spec("polite-1", ["sleep", "100"], tmp_path))
        int_only = sup.start(spec("noint-2", py_node(IGNORE_INT), tmp_path, stdout_path=str(tmp_path / "a")))
        neither = sup.start(spec("stubborn-3", py_node(IGNORE_BOTH), tmp_path, stdout_path=str(tmp_path / "b")))
        await until_async(lambda: all((tmp_path / f).exists() and (tmp_path / f).read_text() for f in "ab"), 10)
        deaths = {}
        for p in (polite, int_only, neither):
            p.popen  # noqa: B018
        t0 = time.monotonic()
        task = asyncio.ensure_future(sup.shutdown())
        while not task.done():
            for p in (polite, int_only, neither):
                if p.name not in deaths and not p.alive:
                    deaths[p.name] = time.monotonic() - t0
            await asyncio.sleep(0.005)
        for p in (polite, int_only, neither):
            deaths.setdefault(p.name, time.monotonic() - t0)
        errors = task.result()
        return deaths, errors, (polite, int_only, neither), time.monotonic() - t0
    deaths, errors, procs, total = asyncio.run(main())
    polite, int_only, neither = procs
    assert polite.exit_code == -signal.SIGINT and deaths["polite-1"] < 0.3
    assert int_only.exit_code == -signal.SIGTERM and 0.4 <= deaths["noint-2"] < 0.65
    assert neither.exit_code == -signal.SIGKILL and 0.7 <= deaths["stubborn-3"] < 1.0
    assert total < 1.2
    err = capsys.readouterr().err
    assert "[noint-2] escalating to SIGTERM" in err and "[noint-2] escalating to SIGKILL" not in err
    assert "[stubborn-3] escalating to SIGKILL" in err
    assert errors == ["process[stubborn-3, pid %d]: required SIGKILL. May still be running." % neither.pid]
    assert "Shutdown errors:\n * process[stubborn-3, pid" in err


def test_stop_reaches_whole_process_group(tmp_path):
    """A node's children (same group) are signalled too, and shutdown waits until they are gone."""
    pidfile = tmp_path / "child.pid"

    async def main():
        sup = Supervisor(sigint_timeout=0.5, sigterm_timeout=0.5)
        # the shell exits at once on SIGINT; its background child ignores SIGINT and needs SIGTERM
        grandchild = ("import os,signal,time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\n"
                      "open(%r, 'w').write(str(os.getpid()))\ntime.sleep(100)" % str(pidfile))
        code = ("import subprocess,sys,time\n"
                "c = subprocess.Popen([sys.executable, '-c', %r])\n"
                "time.sleep(100)" % grandchild)
        p = sup.start(spec("parent-1", py_node(code), tmp_path))
        await until_async(lambda: pidfile.exists() and pidfile.read_text(), 10)
        child = int(pidfile.read_text())
        t0 = time.monotonic()
        await sup.shutdown()
        return p, child, time.monotonic() - t0
    p, child, took = asyncio.run(main())
    assert not pid_alive(child)
    assert 0.5 <= took < 1.5  # waited for the SIGINT-ignoring grandchild, escalated to SIGTERM


def test_pacing_keeps_every_node_on_its_own_clock(tmp_path):
    """Nodes that ignore SIGINT hold a pacing slot only briefly: 8 of them with 2 slots stop in ~timeout + 3 holds."""
    async def main():
        sup = Supervisor(sigint_timeout=0.5, sigterm_timeout=0.5, stop_concurrency=2, stop_hold=0.1)
        files = [tmp_path / ("r%d" % i) for i in range(8)]
        procs = [sup.start(spec("s%d-%d" % (i, i + 1), py_node(IGNORE_INT), tmp_path, stdout_path=str(f)))
                 for i, f in enumerate(files)]
        await until_async(lambda: all(f.read_text() for f in files), 10)
        t0 = time.monotonic()
        await sup.shutdown()
        return procs, time.monotonic() - t0
    procs, took = asyncio.run(main())
    assert all(p.exit_code == -signal.SIGTERM for p in procs)
    # one node at a time through its whole escalation would take 8 x 0.5 s
    assert 0.8 <= took < 1.6, took


def test_inherited_ignored_sigint_is_not_passed_on(tmp_path):
    out = tmp_path / "sig.txt"
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        async def main():
            sup = Supervisor()
            code = "import signal; open(%r,'w').write(str(signal.getsignal(signal.SIGINT) == signal.SIG_IGN))" % str(out)
            p = sup.start(spec("sig-1", [PY, "-c", code], tmp_path))
            await until_async(lambda: not p.alive, 10)
            await sup.shutdown()
        asyncio.run(main())
    finally:
        signal.signal(signal.SIGINT, old)
    # Python maps a default SIGINT to KeyboardInterrupt; an inherited SIG_IGN stays SIG_IGN
    assert out.read_text() == "False"


def test_crash_loop_is_paced(tmp_path):
    """A node that dies at once is restarted about 10 times a second (roslaunch's pace), not in a busy loop."""
    async def main():
        loop = asyncio.get_running_loop()
        starts = []
        sup = Supervisor(on_spawn=lambda proc: starts.append(loop.time()))
        sup.start(spec("crash-1", ["/bin/false"], tmp_path, respawn=True))
        await until_async(lambda: len(starts) >= 6, 10)
        await sup.shutdown()
        return [b - a for a, b in zip(starts, starts[1:])]
    intervals = asyncio.run(main())
    assert min(intervals) >= 0.09, intervals  # paced
    assert sum(intervals) / len(intervals) < 0.3, intervals  # and not slower than roslaunch's 0.1 s loop


def test_children_left_by_earlier_runs_are_stopped_at_shutdown(tmp_path):
    """A node that exits but leaves children in its group, then respawns: shutdown still stops every run's children."""
    pids = tmp_path / "pids"

    async def main():
        sup = Supervisor(sigint_timeout=0.5, sigterm_timeout=0.5)
        code = "sleep 100 & echo $! >> %s; sleep 0.2; exit 1" % pids
        p = sup.start(spec("leaver-1", ["/bin/sh", "-c", code], tmp_path, respawn=True))
        await until_async(lambda: p.spawn_count >= 3 and pids.exists() and len(pids.read_text().split()) >= 3, 10)
        left = [int(x) for x in pids.read_text().split()]
        alive_before = [q for q in left if pid_alive(q)]
        await sup.shutdown()
        return left, alive_before
    left, alive_before = asyncio.run(main())
    assert len(alive_before) >= 2  # the earlier runs' children outlived their parents
    assert not [q for q in left if pid_alive(q)]


def test_the_open_relays_list_costs_a_start_linear_work_and_stays_bounded(tmp_path, monkeypatch):
    """Every screen node's run has a relay; the supervisor keeps the open ones for its shutdown. Rid of the
    closed ones at each spawn, a start of n nodes looked at every relay each time (n^2 / 2 checks); now the list is
    rid of them when it has doubled: a start of 100 nodes is a few hundred checks, and runs that come and go (a
    node restarted for weeks) never grow it past its bound."""
    from launcher.output import screen
    from launcher.process.supervisor import SCREENS_PRUNED_AT
    checks = []
    monkeypatch.setattr(screen.ScreenOutput, "closed", property(lambda self: checks.append(1) or not self.sources))

    async def start_many() -> int:
        sup = Supervisor(exit_when_all_dead=False)
        started = [sup.start(spec("many-%d" % i, ["/bin/true"], tmp_path, output="screen")) for i in range(100)]
        at_start = len(checks)
        await until_async(lambda: not any(p.alive for p in started), 30)
        await sup.shutdown()
        sup.close()
        return at_start

    async def one_after_another() -> int:
        sup = Supervisor(exit_when_all_dead=False)
        longest = 0
        for i in range(3 * SCREENS_PRUNED_AT):  # each run over before the next
            p = sup.start(spec("again-%d" % i, ["/bin/true"], tmp_path, output="screen"))
            relay = sup.screens[-1]
            longest = max(longest, len(sup.screens))
            await until_async(lambda: not p.alive and relay.closed, 10)
        await sup.shutdown()
        sup.close()
        return longest
    at_start = asyncio.run(start_many())
    assert 0 < at_start < 4 * 100, at_start  # (the scan at every spawn: 4,950)
    longest = asyncio.run(one_after_another())
    assert longest <= SCREENS_PRUNED_AT + 2, longest  # (never pruned: 48)


def test_a_shutdown_without_ordered_nodes_waits_once_for_all_ends(tmp_path, monkeypatch):
    """Woken at each node's end, a shutdown looked at every node again each time (n ends: n^2 looks, and n waits
    on up to n futures): with no node to hold back until another is down, it waits once for every end."""
    waits = []
    real_wait = asyncio.wait

    async def counted(futures, **kw):
        waits.append(len(futures))
        return await real_wait(futures, **kw)
    monkeypatch.setattr(asyncio, "wait", counted)
    # five nodes that end one after another, 0.1 s apart, at their SIGINT
    code = ("import signal,sys,time\nsignal.signal(signal.SIGINT, lambda *a: (time.sleep(%s), sys.exit(0)))\n"
            "open(sys.argv[1], 'w').close()\ntime.sleep(100)")

    async def main():
        sup = Supervisor(exit_when_all_dead=False)
        started = [sup.start(spec("staggered-%d" % i, py_node(code % (0.1 * i)) + [str(tmp_path / str(i))], tmp_path))
                   for i in range(5)]
        await until_async(lambda: all((tmp_path / str(i)).exists() for i in range(5)), 10, what="their handlers")
        await sup.shutdown()
        return started
    started = asyncio.run(main())
    assert not any(pid_alive(p.pid) for p in started)
    assert waits == [5]
