"""MasterState: a master found running that restarts, told from its answers (pure: no master, no clock)."""

from __future__ import annotations

from launcher.services.masterwatch import (BACK, DOWN, RESTARTED, RESTING_GAP, SAME, UNSEEN_ASKS, Answer,
                                          MasterState)


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


def test_a_run_never_seen_registered_is_asked_about_at_doubling_gaps_up_to_the_resting_gap():
    s = MasterState("r1")
    running = {"/plain": 12}
    asked_in, resting_in = [], []
    for round_ in range(1, 61):
        names = s.to_ask(running)
        if names:
            asked_in.append(round_)
        if s.resting(running):
            resting_in.append(round_)
        s.seen(Answer(True, "r1", tuple(names), ()), running)
    # each round for UNSEEN_ASKS (5) rounds; then after 2, 4, 8 and 16 rounds, and every 16 from then on
    assert UNSEEN_ASKS == 5 and RESTING_GAP == 16
    assert asked_in == [1, 2, 3, 4, 5, 7, 11, 19, 35, 51]
    assert resting_in == [r for r in range(1, 61) if r not in asked_in]  # the rounds between: resting


def test_a_late_registration_is_seen_at_the_next_ask_and_a_respawn_is_asked_about_at_once():
    s = MasterState("r1")
    running = {"/slow": 30}
    for _ in range(7):  # rounds 1..7: misses at 1-5 and 7; the next ask is round 11
        s.seen(Answer(True, "r1", tuple(s.to_ask(running)), ()), running)
    assert [s.to_ask(running) for _ in range(3)] == [[], [], []]  # rounds 8-10: resting
    assert s.to_ask(running) == ["/slow"]  # round 11: asked, and now registered
    s.seen(Answer(True, "r1", ("/slow",), ("/slow",)), running)
    assert s.to_ask(running) == [] and s.resting(running) == []  # seen: not asked, not resting
    assert s.restarted("r2", running) == ["/slow"]  # (a registered run goes with the master)
    for _ in range(9):
        s.seen(Answer(True, "r2", tuple(s.to_ask(running)), ()), running)
    assert s.resting(running) == ["/slow"]
    running["/slow"] = 31  # respawned: its new run is asked about at once, its misses start over
    assert s.to_ask(running) == ["/slow"]
    s.seen(Answer(True, "r2", ("/slow",), ()), running)
    assert s.runs["/slow"].misses == 1 and s.to_ask(running) == ["/slow"]


def test_the_watch_asks_about_no_node_that_says_it_never_registers_and_not_about_a_resting_one():
    from types import SimpleNamespace

    from launcher.fleet import lifecycle
    from launcher.model.config import NodePolicy
    from launcher.model.graph import NODE, Graph
    from launcher.services.masterwatch import MasterWatch

    def rec(name: str, pid: int, registers: bool = True, host: str = "localhost") -> lifecycle.Record:
        rules = lifecycle.Rules(policy=NodePolicy(registers=registers))
        return lifecycle.Record(name, name.strip("/"), host, rules, state=lifecycle.RUNNING, pid=pid)
    records = [rec("/driver", 10), rec("/script", 11, registers=False), rec("/plain", 12),
               rec("/remote", 13, host="robot2")]
    graph = Graph()
    graph.want("a held node", {(NODE, "/plain"), (NODE, "/other")})
    session = SimpleNamespace(uri="http://localhost:11311/", run_id="r1", graph=graph)
    nodes = SimpleNamespace(fleet=SimpleNamespace(records={r.name: r for r in records}), supervisor=None)
    watch = MasterWatch(session, nodes)
    running = watch._running()
    assert running == {"/driver": 10, "/plain": 12}  # never /script: its registers="false" says it is no ROS node
    for _ in range(7):  # rounds 1-7: /driver registers at once, /plain never does (asked in 1-5 and 7)
        names = watch.state.to_ask(running)
        watch.state.seen(Answer(True, "r1", tuple(names), ("/driver",)), running)
    records[0] = records[0]._replace(registered=True)
    nodes.fleet.records["/driver"] = records[0]
    assert watch.state.to_ask(running) == [] and watch.state.resting(running) == ["/plain"]  # round 8
    # the remote node is asked about as the fleet's; /plain only because a held node waits for it
    assert watch._graph_names([], watch.state.resting(running)) == ["/other", "/plain", "/remote"]
    graph.want("a held node", set())
    assert watch._graph_names([], watch.state.resting(running)) == ["/remote"]
