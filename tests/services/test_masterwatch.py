"""MasterState: a master found running that restarts, told from its answers (pure: no master, no clock)."""

from __future__ import annotations

from launcher.services.masterwatch import (BACK, DOWN, RESTARTED, SAME, UNSEEN_ASKS, Answer, MasterState)


def ask(state: MasterState, running: dict, run_id="r1", registered=()) -> str:
    return state.seen(Answer(True, run_id, tuple(state.to_ask(running)), tuple(registered)), running)


def test_the_same_run_id_is_nothing_new_and_a_silence_is_said_once():
    s = MasterState("r1")
    assert ask(s, {}) == SAME
    assert s.seen(Answer(False), {}) == DOWN
    assert s.seen(Answer(False), {}) == SAME
    assert ask(s, {}) == BACK  # the same run id: it kept its state
    assert ask(s, {}) == SAME


def test_a_changed_or_missing_run_id_is_a_restart_whether_or_not_a_silence_was_seen():
    s = MasterState("r1")
    assert ask(s, {}, run_id="r2") == RESTARTED
    s.restarted("r2", {})
    assert s.seen(Answer(False), {}) == DOWN
    assert ask(s, {}, run_id=None) == RESTARTED  # a bare rosmaster has no /run_id at all


def test_the_nodes_restarted_are_those_seen_registered_or_not_yet_asked_about():
    s = MasterState("r1")
    running = {"/a": 10, "/b": 11, "/plain": 12}
    assert s.to_ask(running) == ["/a", "/b", "/plain"]
    ask(s, running, registered=["/a"])
    assert s.to_ask(running) == ["/b", "/plain"]  # a run seen registered is not asked about again
    ask(s, running, registered=["/b"])
    for _ in range(UNSEEN_ASKS):
        ask(s, running)  # /plain never registers: not a ROS node
    running["/new"] = 13  # started since the last ask
    running["/a"] = 20  # respawned since: this run not seen yet
    assert ask(s, running, run_id="r2") == RESTARTED
    assert s.restarted("r2", running) == ["/a", "/b", "/new"]
    assert sorted(s.to_ask(running)) == ["/a", "/b", "/new", "/plain"]  # every run is asked about anew
