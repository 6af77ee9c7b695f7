"""A machine's session with its child as pure state: what comes after a session, and the protocol's words."""

from __future__ import annotations

from launcher.fleet import lifecycle as m
from launcher.remote import session as s


def test_a_machine_never_reached_fails_once():
    state, after = s.after_session(s.started(s.Session()), registered=False, lost=False, queued=True)
    assert after == s.Next(s.GIVE_UP)


def test_drops_are_retried_with_a_delay_that_doubles_up_to_its_cap_and_resets_after_a_good_session():
    state = s.accepting(s.started(s.Session()))
    delays = []
    for _ in range(7):
        state, after = s.after_session(state, registered=True, lost=True, queued=True)
        assert after.what == s.RETRY and after.dropped
        delays.append(after.delay)
        state = s.started(state)  # (the next session: it does not register, the link still cut)
        state, after = s.after_session(state, registered=False, lost=False, queued=True)
        assert after.what == s.RETRY and after.dropped  # reached once: a drop, not a failed machine
        delays.append(after.delay)
        state = s.accepting(s.started(state))
    assert delays[:6] == [1.0, 2.0, 4.0, 8.0, 16.0, 30.0] and max(delays) == s.RETRY_MAX_S
    state = s.launched(state)
    state, after = s.after_session(state, registered=True, lost=False, queued=False)
    assert after == s.Next(s.IDLE) and state.delay == s.RETRY_FIRST_S


def test_a_child_that_ended_with_its_last_node_gets_a_new_session_only_for_a_node_to_start():
    state = s.launched(s.accepting(s.started(s.Session())))
    state = s.ending(state)
    assert state.phase == s.ENDING
    assert s.after_session(state, registered=True, lost=False, queued=False)[1] == s.Next(s.IDLE)
    assert s.after_session(state, registered=True, lost=False, queued=True)[1] == s.Next(s.RETRY, 0.0)
    # a session that started nothing and ended with nodes queued (its child refused them): after a delay
    refused = s.ending(s.accepting(s.started(s.Session())))
    assert s.after_session(refused, registered=True, lost=False, queued=True)[1] == s.Next(s.RETRY, 1.0)


def test_the_protocols_words():
    assert s.started_line("process[robot/talker-3]: started with pid [4242]") == ("robot/talker-3", 4242)
    assert s.started_line("process[talker-3]: started with pid") is None
    assert s.node_of_process("robot/talker-12") == "robot/talker" and s.node_of_process("x") == "x"
    assert s.died(-9) == (None, 9) and s.died(3) == (3, None) and s.died("?") == (None, None)


def test_a_child_ends_when_its_last_node_is_gone_after_a_start_that_succeeded():
    launched = s.launched(s.accepting(s.started(s.Session())))
    gone = [(m.EXITED, True), (m.STOPPED, False), (m.FATAL, True), (m.RESPAWNING, True), (m.PENDING, False)]
    assert s.child_ends(launched, gone)
    for state in (m.LAUNCHING, m.RUNNING, m.STOPPING):  # a process on the child, or one being given to it
        for owned in (True, False):
            assert not s.child_ends(launched, gone + [(state, owned)]), (state, owned)
    # a node the child respawns itself is its own while it respawns; one the parent restarts is not
    assert not s.child_ends(launched, gone + [(m.RESPAWNING, False)])
    # after starts that all failed the child lives on (Debian's ends only when a node died)
    assert not s.child_ends(s.accepting(s.started(s.Session())), gone)
    assert s.QUEUED == {m.PENDING, m.LOST}


def test_a_childs_log_calls_and_refusals_in_words():
    assert s.log_kind(8, "process[talker-1]: started with pid [7]") == (s.ERROR, None)
    assert s.log_kind(16, "x") == (s.ERROR, None)
    assert s.log_kind(2, "process[ns/talker-1]: started with pid [7]") == (s.STARTED, ("ns/talker-1", 7))
    assert s.log_kind(2, "started with pid, garbled") == (s.STARTED, None)
    assert s.log_kind("8", "hello") == (s.INFO, None) and s.log_kind(4, "hello") == (s.INFO, None)
    assert s.stop_refusal("method [stop_process] is not supported") == s.NO_STOP_PROCESS
    assert s.stop_refusal("no process [x]") == "no process [x]"
