"""enable_coredumps: only that node may dump core, and when it does the launcher says where the core went."""

from __future__ import annotations

import asyncio
import os
import resource

import pytest

from launcher.model.config import NodePolicy
from launcher.process.coredumps import CoreDumpReporter, core_location
from launcher.process.supervisor import Supervisor

from tests.process.health import console_err, python_node

ABORT = "import os\nos.abort()"


def crash(tmp_path, policy):
    async def main():
        sup = Supervisor()
        sup.watchers.append(CoreDumpReporter())
        proc = sup.start(python_node(tmp_path, "crasher", ABORT, policy=policy))
        sup.registrations_complete()
        await asyncio.wait_for(sup.done.wait(), 30)
        await sup.shutdown()
        return proc
    return asyncio.run(main())


def cores(tmp_path):
    return [f for f in os.listdir(tmp_path) if f.startswith("core")]


def test_a_node_with_enable_coredumps_dumps_core_and_says_where(tmp_path, capsys):
    pattern = open("/proc/sys/kernel/core_pattern").read().strip()
    if resource.getrlimit(resource.RLIMIT_CORE)[1] == 0:
        pytest.skip("the hard core limit is 0 here: no process may dump core")
    soft_before = resource.getrlimit(resource.RLIMIT_CORE)
    proc = crash(tmp_path, NodePolicy(enable_coredumps=True))
    assert resource.getrlimit(resource.RLIMIT_CORE) == soft_before  # the launcher's own limit is unchanged
    err = console_err(capsys)
    assert "[crasher-1] dumped core (signal 6): " in err
    if pattern.startswith("|"):
        assert ("coredumpctl gdb %d" % proc.pid in err) or "apport" in err or "piped to" in err
    else:
        where = core_location(proc.pid, str(tmp_path), "python3")
        assert cores(tmp_path), "no core file in the node's working directory"
        assert "core dumped to %s" % os.path.join(str(tmp_path), cores(tmp_path)[0]) in err or where in err


def test_without_enable_coredumps_no_core_and_no_word(tmp_path, capsys):
    if resource.getrlimit(resource.RLIMIT_CORE)[0] != 0:
        pytest.skip("the launcher's own core limit is not 0 here")
    crash(tmp_path, None)
    assert "dumped core" not in console_err(capsys)
    assert not cores(tmp_path)


def test_core_location_follows_the_core_pattern():
    assert core_location(42, "/w", "talker", "|/lib/systemd/systemd-coredump %P %u", False) == \
        "get it with: coredumpctl gdb 42"
    assert core_location(42, "/w", "talker", "core", True) == "/w/core.42"
    assert core_location(42, "/w", "talker", "core", False) == "/w/core"
    assert core_location(42, "/w", "talker", "/var/cores/%e.%p.%%", False) == "/var/cores/talker.42.%"
    assert "apport" in core_location(42, "/w", "talker", "|/usr/share/apport/apport -p%p", False)
