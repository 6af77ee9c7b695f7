"""The launch's phase as a pure function: every phase x event against a matrix written out here (the next phase
and the actions), for a launch with its own master and one with a master found running, and roslaunch's rules
for the exit status, "all processes on machine have died" and "No processes to monitor"."""

from __future__ import annotations

import pytest

from launcher.fleet import launchphase as lp
from launcher.fleet import lifecycle
from launcher.fleet.launchphase import Action, Event, Launch

EVENTS = [lp.ALL_STARTED, lp.NODE_ENDED_IT, lp.START_FAILED, lp.ALL_DEAD, lp.NO_PROCESSES, lp.STOP_SIGNAL, lp.STOP,
          lp.ALL_STOPPED]
SHORT = {"sta": lp.STARTING, "run": lp.RUNNING, "eng": lp.ENDING, "sto": lp.STOPPING, "end": lp.ENDED}
# Every cell: the phase after the event ("-": nothing changes, "!": a runner's bug, InvalidTransition), and (in
# the matrix below it) the actions, in their order: E end with the node's status (3 in these cells), F end with
# status 1 (a start that failed), Z end with status 0, S say "all processes on machine have died, roslaunch will
# exit", N say "No processes to monitor" in bold, P stop all, K kill all; ".": none. S and N give the launch its
# reason (their words).
ACTION_CODES = {"E": Action(lp.END, status=3), "F": Action(lp.END, status=1), "Z": Action(lp.END, status=0),
                "S": Action(lp.SAY, text=lp.ALL_DEAD_TEXT), "N": Action(lp.SAY, text=lp.NO_PROCESSES_TEXT, bold=True),
                "P": Action(lp.STOP_ALL), "K": Action(lp.KILL_ALL)}

# roslaunch's own master (launch, roscore): the launch runs on when its nodes have all died, or it has none.
#        ALLST NODE  START DEAD  NOPROC SIGNL STOP  ALLSTOPPED
OWN = """
sta      run   eng   eng   -     !      eng   sto   !
run      -     eng   -     -     -      eng   sto   !
eng      -     eng   -     -     -      -     sto   !
sto      -     sto   -     -     -      sto   -     end
end      !     -     !     -     !      -     -     !
"""
OWN_ACTIONS = """
sta      .     E     F     .     !      .     P     !
run      .     E     .     .     .      .     P     !
eng      .     E     .     .     .      .     P     !
sto      .     E     .     .     .      K     .     .
end      !     .     !     .     !      .     .     !
"""
# A master found running: the launch ends when every node of this machine has died, or when it has no process.
#        ALLST NODE  START DEAD  NOPROC SIGNL STOP  ALLSTOPPED
EXTERNAL = """
sta      run   eng   eng   -     !      eng   sto   !
run      -     eng   -     eng   eng    eng   sto   !
eng      -     eng   -     -     -      -     sto   !
sto      -     sto   -     -     -      sto   -     end
end      !     -     !     -     !      -     -     !
"""
EXTERNAL_ACTIONS = """
sta      .     E     F     .     !      .     P     !
run      .     E     .     SZ    NZ     .     P     !
eng      .     E     .     .     .      .     P     !
sto      .     E     .     .     .      K     .     .
end      !     .     !     .     !      .     .     !
"""
# A remote child (a runner on its own too): as with a master found running, but a node's start that fails is its
# node's business (roslaunch's child answers its parent's launch call with the error and goes on).
#        ALLST NODE  START DEAD  NOPROC SIGNL STOP  ALLSTOPPED
CHILD = """
sta      run   eng   -     -     !      eng   sto   !
run      -     eng   -     eng   eng    eng   sto   !
eng      -     eng   -     -     -      -     sto   !
sto      -     sto   -     -     -      sto   -     end
end      !     -     !     -     !      -     -     !
"""
CHILD_ACTIONS = """
sta      .     E     .     .     !      .     P     !
run      .     E     .     SZ    NZ     .     P     !
eng      .     E     .     .     .      .     P     !
sto      .     E     .     .     .      K     .     .
end      !     .     !     .     !      .     .     !
"""
# (exit_when_all_dead, start_failure_ends_it, phases, actions)
TABLES = {"own master": (False, True, OWN, OWN_ACTIONS), "external master": (True, True, EXTERNAL, EXTERNAL_ACTIONS),
          "remote child": (True, False, CHILD, CHILD_ACTIONS)}


def _rows(text: str) -> list[list[str]]:
    rows = [line.split() for line in text.strip().splitlines()]
    for row in rows:
        assert len(row) == len(EVENTS) + 1, row[0]
    return rows


def cells():
    for table, (all_dead_ends, start_failure_ends, phases, actions) in TABLES.items():
        for row, acts in zip(_rows(phases), _rows(actions)):
            assert row[0] == acts[0]
            for kind, expected, codes in zip(EVENTS, row[1:], acts[1:]):
                yield table, (all_dead_ends, start_failure_ends), SHORT[row[0]], kind, expected, codes


def test_the_matrices_cover_every_phase_and_event():
    for table, (_rule, _other, phases, actions) in TABLES.items():
        assert [r[0] for r in _rows(phases)] == [r[0] for r in _rows(actions)] == list(SHORT), table
    assert set(SHORT.values()) == set(lp.STATES)
    assert set(EVENTS) == set(lp.EVENTS)


def test_every_pair_is_done_ignored_or_refused_and_only_one_of_them():
    pairs = {(s, k) for s in lp.STATES for k in lp.EVENTS}
    done, ignored, refused = set(lp.TABLE), set(lp.IGNORED), set(lp.REFUSED)
    assert done | ignored | refused == pairs
    assert not (done & ignored or done & refused or ignored & refused)
    for _table, _rule, phase, kind, expected, _codes in cells():
        assert (expected == "!") == ((phase, kind) in refused), (phase, kind)
        if (phase, kind) in ignored:
            assert expected == "-", (phase, kind)


@pytest.mark.parametrize("table,rule,phase,kind,expected,codes", list(cells()),
                         ids=lambda x: x if isinstance(x, str) else "")
def test_every_phase_and_event(table, rule, phase, kind, expected, codes):
    before = Launch(phase, exit_when_all_dead=rule[0], start_failure_ends_it=rule[1])
    event = Event(kind, status=3)
    if expected == "!":
        assert codes == "!"
        with pytest.raises(lp.InvalidTransition):
            lp.step(before, event)
        return
    after, actions = lp.step(before, event)
    if expected == "-":
        assert after == before and actions == [] and codes == "."
        return
    assert after.state == SHORT[expected]
    assert actions == [ACTION_CODES[c] for c in codes if c != "."]
    assert after.exit_status == (3 if "E" in codes else 1 if "F" in codes else 0)
    assert (after.exit_when_all_dead, after.start_failure_ends_it) == rule
    assert after.reason == (lp.ALL_DEAD_TEXT if "S" in codes else lp.NO_PROCESSES_TEXT if "N" in codes else "")


def test_the_first_node_that_fails_decides_the_exit_status():
    launch = Launch(lp.RUNNING)
    launch, actions = lp.step(launch, Event(lp.NODE_ENDED_IT, status=0))  # a required node that exited with 0
    assert (launch.state, launch.exit_status, actions) == (lp.ENDING, 0, [Action(lp.END, status=0)])
    launch, actions = lp.step(launch, Event(lp.NODE_ENDED_IT, status=137))  # ... then one killed by SIGKILL
    assert (launch.exit_status, actions) == (137, [Action(lp.END, status=137)])
    launch, actions = lp.step(launch, Event(lp.NODE_ENDED_IT, status=1))  # ... a later failure changes nothing
    assert (launch.exit_status, actions) == (137, [Action(lp.END, status=137)])
    launch, _ = lp.step(launch, Event(lp.STOP))
    launch, actions = lp.step(launch, Event(lp.NODE_ENDED_IT, status=2))  # (a deferred one, during the stop)
    assert (launch.state, launch.exit_status, actions) == (lp.STOPPING, 137, [Action(lp.END, status=137)])


def test_a_launch_from_start_to_end_with_two_ctrl_cs():
    launch = Launch(exit_when_all_dead=True)
    seen = []
    for kind in (lp.ALL_STARTED, lp.STOP_SIGNAL, lp.STOP_SIGNAL, lp.ALL_DEAD, lp.STOP, lp.STOP_SIGNAL,
                 lp.ALL_STOPPED, lp.STOP_SIGNAL):
        launch, actions = lp.step(launch, Event(kind))
        seen.append((launch.state, [a.kind for a in actions]))
    assert seen == [(lp.RUNNING, []), (lp.ENDING, []), (lp.ENDING, []), (lp.ENDING, []),
                    (lp.STOPPING, [lp.STOP_ALL]), (lp.STOPPING, [lp.KILL_ALL]), (lp.ENDED, []), (lp.ENDED, [])]


def test_which_phases_let_nodes_start_and_which_stop_them():
    assert [s for s in lp.STATES if lp.starts_allowed(Launch(s))] == [lp.STARTING, lp.RUNNING]
    assert [s for s in lp.STATES if lp.stopping(Launch(s))] == [lp.STOPPING, lp.ENDED]


class _R:
    def __init__(self, state):
        self.state = state


def test_all_dead_is_roslaunchs_all_processes_on_machine_have_died():
    def dead(states, unstarted=0):
        return lp.all_dead([_R(s) for s in states], lifecycle.ALIVE, lifecycle.ENDED, unstarted)
    assert dead([lifecycle.EXITED, lifecycle.FATAL])
    assert dead([lifecycle.EXITED, lifecycle.STOPPED])
    assert not dead([lifecycle.EXITED, lifecycle.RESPAWNING])  # (it runs again)
    assert not dead([lifecycle.EXITED, lifecycle.NEW])
    assert not dead([lifecycle.STOPPED])  # (an operator stopped them: none died)
    assert not dead([])
    assert dead([], unstarted=1)  # (the only node's command could not be made)
    assert dead([lifecycle.STOPPED], unstarted=1)
    assert not dead([lifecycle.RUNNING], unstarted=1)

