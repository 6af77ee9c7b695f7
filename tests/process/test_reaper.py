"""The reaper's choice: zombie children that are no runner's (not a supervised node, not in the launch's group)."""

from __future__ import annotations

import os

from launcher.process import reaper


def fake_proc(root, pid: int, kids: dict[int, tuple[str, int]]) -> str:
    """A /proc with `pid`'s children (child -> (state, pgrp)), spread over two threads."""
    task = root / str(pid) / "task"
    items = sorted(kids)
    for tid, share in ((pid, items[::2]), (pid + 1, items[1::2])):
        (task / str(tid)).mkdir(parents=True)
        (task / str(tid) / "children").write_text(" ".join(map(str, share)) + " ")
    for kid, (state, pgrp) in kids.items():
        (root / str(kid)).mkdir()
        (root / str(kid) / "stat").write_bytes(b"%d (a (b) c) %s %d %d 0" % (kid, state.encode(), pid, pgrp))
    return str(root)


def test_only_orphan_zombies_outside_the_launch_group(tmp_path):
    proc = fake_proc(tmp_path, 1, {10: ("Z", 10), 11: ("Z", 1), 12: ("S", 12), 13: ("Z", 50), 14: ("Z", 14)})
    assert sorted(reaper.children(1, proc)) == [10, 11, 12, 13, 14]
    # 10 is a supervised node (its runner reaps it by pidfd); 11 is in the launch's own group (du, ssh)
    assert reaper.orphan_zombies(1, own=[10], pgrp=1, proc=proc) == [13, 14]



def test_a_supervised_nodes_stat_is_never_read(tmp_path, monkeypatch):
    """Every node's exit is a SIGCHLD: the reaper reads /proc only for the children no runner owns (else a fleet
    of n stopping together costs n * n reads)."""
    kids = {pid: ("Z" if pid % 2 else "S", pid) for pid in range(10, 40)}
    proc = fake_proc(tmp_path, 1, kids)
    read = []
    real = reaper.stat_fields
    monkeypatch.setattr(reaper, "stat_fields", lambda pid, proc="/proc": read.append(pid) or real(pid, proc))
    own = [pid for pid in kids if pid != 31]
    assert reaper.orphan_zombies(1, own=own, pgrp=1, proc=proc) == [31]
    assert read == [31]

def test_stat_fields_survive_parentheses_in_the_name(tmp_path):
    fake_proc(tmp_path, 1, {7: ("Z", 3)})
    assert reaper.stat_fields(7, str(tmp_path))[:3] == ["Z", "1", "3"]
    assert reaper.stat_fields(8, str(tmp_path)) is None


def test_children_of_this_process_are_real():
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    try:
        assert pid in reaper.children(os.getpid())
    finally:
        os.waitpid(pid, 0)
