"""The node state machine as a pure function: every state x event against a matrix written out here, the
remote sub-states, the cases that were bugs, and invariants checked by hypothesis."""

from __future__ import annotations

import pytest
from hypothesis import given, settings, strategies as st

from launcher.model.config import NodePolicy
from launcher.fleet import lifecycle as m
from launcher.fleet.lifecycle import Action, Event, Record, Rules

# Columns: the events, in this order.
EVENTS = [m.START, m.KEEP_STOPPED, m.DUE, m.READY, m.NOT_READY, m.SPAWNED, m.SPAWN_FAILED, m.PROCESS_EXITED, m.HANG,
          m.STALL, m.UNSTALL, m.RESTART, m.LIMIT, m.STOP, m.SHUTDOWN, m.DOWN, m.STOP_REFUSED, m.OPERATOR_START, m.LAUNCH_SENT,
          m.LAUNCHED, m.LAUNCH_REFUSED, m.LINK_LOST, m.MACHINE_FAILED, m.BOUND_ENDED, m.BOUND_STARTED,
          m.RELOAD_STOP, m.RENEW, m.RULES, m.REGISTERED, m.UNREGISTERED]
SHORT = {"new": m.NEW, "del": m.DELAYED, "hel": m.HELD, "sta": m.STARTING, "pen": m.PENDING, "lau": m.LAUNCHING,
         "run": m.RUNNING, "hun": m.HUNG, "stl": m.STALLED, "sto": m.STOPPING, "res": m.RESPAWNING, "los": m.LOST, "exi": m.EXITED,
         "fat": m.FATAL, "stp": m.STOPPED, "det": m.DETACHED}
# Every cell: the state after the event, and (in the matrix of actions below it) what the runner is told to do.
# States: "-": changes nothing (a late report, a second stop ...); "!": a runner's bug (InvalidTransition); else
# the state after the event. Actions, in their order: S spawn, L launch (its machine's child), T schedule (a
# timer), C cancel, H hold (readiness), B begin stop, K kill, E end the launch, N note; ".": none.
ACTION_CODES = {"S": m.SPAWN, "L": m.LAUNCH, "T": m.SCHEDULE, "C": m.CANCEL, "H": m.HOLD, "B": m.BEGIN_STOP,
                "K": m.KILL, "E": m.END_LAUNCH, "N": m.NOTE}

# A respawning node of this machine.
#        START KEEP  DUE   READY NRDY  SPAWN SFAIL EXIT  HANG  STALL UNSTL RSTRT LIMIT STOP  SHUTD DOWN  SREF  OSTRT LSENT LCHD  LREF  LLOST MFAIL BEND  BSTRT RSTOP RENEW RULES REG   UNREG
MATRIX = """
new      sta   stp   !     !     !     !     !     !     !     !     -     !     -     stp   stp   !     !     sta   !     !     !     -     exi   -     -     stp   new   new   -     -
del      !     !     sta   !     !     !     !     !     !     !     -     !     -     stp   stp   !     !     sta   !     !     !     -     exi   -     -     stp   !     del   -     -
hel      !     !     !     sta   exi   !     !     !     !     !     -     !     -     stp   stp   !     !     sta   !     !     !     -     exi   det   -     stp   !     hel   -     -
sta      !     !     !     !     !     run   res   !     !     !     -     -     -     !     !     !     !     -     !     !     !     !     !     -     -     !     !     sta   -     -
pen      !     !     !     !     !     !     -     -     !     !     -     !     -     stp   stp   !     !     -     lau   -     -     -     exi   !     !     stp   !     pen   -     -
lau      !     !     !     !     !     run   res   res   !     !     -     !     -     sto   stp   !     !     -     !     lau   pen   los   exi   !     !     stp   !     lau   lau   -
run      !     !     !     !     !     run   !     res   hun   stl   -     run   run   sto   sto   !     !     -     !     run   -     los   exi   sto   -     sto   !     run   run   -
hun      !     !     !     !     !     !     !     res   -     -     -     -     -     sto   sto   !     !     -     !     !     !     !     !     sto   -     sto   !     hun   hun   -
stl      !     !     !     !     !     !     !     res   hun   -     run   -     -     sto   sto   !     !     -     !     !     !     !     !     sto   -     sto   !     stl   stl   -
sto      !     !     !     !     !     -     !     sto   -     -     -     -     -     -     -     stp   run   -     !     -     !     stp   -     -     -     -     !     sto   sto   -
res      !     !     sta   !     !     run   !     !     -     -     -     -     -     stp   stp   !     !     sta   !     !     -     -     exi   det   -     stp   !     res   -     -
los      !     !     !     !     !     -     -     -     !     !     -     !     -     stp   stp   !     !     -     lau   -     -     -     exi   !     !     stp   !     los   -     -
exi      sta   !     -     -     -     !     !     -     -     -     -     -     -     -     -     !     !     sta   !     -     -     -     -     det   -     -     new   exi   -     -
fat      sta   !     -     -     -     !     !     -     -     -     -     -     -     -     -     !     !     sta   !     -     -     -     -     det   -     -     new   fat   -     -
stp      sta   !     -     -     -     -     -     -     -     -     -     -     -     -     -     !     !     sta   !     -     -     -     -     -     -     -     new   stp   -     -
det      !     !     -     !     !     !     !     -     -     -     -     -     -     stp   stp   !     !     sta   !     -     -     -     -     -     sta   stp   new   det   -     -
"""
#        START KEEP  DUE   READY NRDY  SPAWN SFAIL EXIT  HANG  STALL UNSTL RSTRT LIMIT STOP  SHUTD DOWN  SREF  OSTRT LSENT LCHD  LREF  LLOST MFAIL BEND  BSTRT RSTOP RENEW RULES REG   UNREG
ACTIONS = """
new      S     .     !     !     !     !     !     !     !     !     .     !     .     C     C     !     !     CS    !     !     !     .     C     .     .     C     .     .     .     .
del      !     !     S     !     !     !     !     !     !     !     .     !     .     C     C     !     !     CS    !     !     !     .     C     .     .     C     !     .     .     .
hel      !     !     !     S     .     !     !     !     !     !     .     !     .     C     C     !     !     CS    !     !     !     .     C     C     .     C     !     .     .     .
sta      !     !     !     !     !     .     T     !     !     !     .     .     .     !     !     !     !     .     !     !     !     !     !     .     .     !     !     .     .     .
pen      !     !     !     !     !     !     .     .     !     !     .     !     .     C     C     !     !     .     .     .     .     .     C     !     !     C     !     .     .     .
lau      !     !     !     !     !     .     T     T     !     !     .     !     .     B     C     !     !     .     !     .     .     .     C     !     !     C     !     .     .     .
run      !     !     !     !     !     .     !     T     K     K     .     K     .     B     B     !     !     .     !     .     .     .     C     B     .     B     !     .     .     .
hun      !     !     !     !     !     !     !     T     .     .     .     .     .     B     B     !     !     .     !     !     !     !     !     B     .     B     !     .     .     .
stl      !     !     !     !     !     !     !     T     K     .     .     .     .     B     B     !     !     .     !     !     !     !     !     B     .     B     !     .     .     .
sto      !     !     !     !     !     .     !     .     .     .     .     .     .     .     .     .     .     .     !     .     !     .     .     .     .     .     !     .     .     .
res      !     !     S     !     !     .     !     !     .     .     .     .     .     C     C     !     !     CS    !     !     .     .     C     C     .     C     !     .     .     .
los      !     !     !     !     !     .     .     .     !     !     .     !     .     C     C     !     !     .     .     .     .     .     C     !     !     C     !     .     .     .
exi      S     !     .     .     .     !     !     .     .     .     .     .     .     .     .     !     !     CS    !     .     .     .     .     C     .     .     .     .     .     .
fat      S     !     .     .     .     !     !     .     .     .     .     .     .     .     .     !     !     CS    !     .     .     .     .     C     .     .     .     .     .     .
stp      S     !     .     .     .     .     .     .     .     .     .     .     .     .     .     !     !     CS    !     .     .     .     .     .     .     .     .     .     .     .
det      !     !     .     !     !     !     !     .     .     .     .     .     .     C     C     !     !     CS    !     .     .     .     .     .     S     C     .     .     .     .
"""

# A node of another machine whose child respawns it (no policy of the parent's: roslaunch's remote respawn).
#        START KEEP  DUE   READY NRDY  SPAWN SFAIL EXIT  HANG  STALL UNSTL RSTRT LIMIT STOP  SHUTD DOWN  SREF  OSTRT LSENT LCHD  LREF  LLOST MFAIL BEND  BSTRT RSTOP RENEW RULES REG   UNREG
REMOTE_MATRIX = """
new      pen   stp   !     !     !     !     !     !     !     !     -     !     -     stp   stp   !     !     pen   !     !     !     -     exi   -     -     stp   new   new   -     -
del      !     !     pen   !     !     !     !     !     !     !     -     !     -     stp   stp   !     !     pen   !     !     !     -     exi   -     -     stp   !     del   -     -
hel      !     !     !     pen   exi   !     !     !     !     !     -     !     -     stp   stp   !     !     pen   !     !     !     -     exi   det   -     stp   !     hel   -     -
sta      !     !     !     !     !     run   res   !     !     !     -     -     -     !     !     !     !     -     !     !     !     !     !     -     -     !     !     sta   -     -
pen      !     !     !     !     !     !     -     -     !     !     -     !     -     stp   stp   !     !     -     lau   -     -     -     exi   !     !     stp   !     pen   -     -
lau      !     !     !     !     !     run   res   res   !     !     -     !     -     sto   stp   !     !     -     !     lau   pen   los   exi   !     !     stp   !     lau   lau   -
run      !     !     !     !     !     run   !     res   hun   stl   -     run   run   sto   sto   !     !     -     !     run   -     los   exi   sto   -     sto   !     run   run   -
hun      !     !     !     !     !     !     !     res   -     -     -     -     -     sto   sto   !     !     -     !     !     !     !     !     sto   -     sto   !     hun   hun   -
stl      !     !     !     !     !     !     !     res   hun   -     run   -     -     sto   sto   !     !     -     !     !     !     !     !     sto   -     sto   !     stl   stl   -
sto      !     !     !     !     !     -     !     sto   -     -     -     -     -     -     -     stp   run   -     !     -     !     stp   -     -     -     -     !     sto   sto   -
res      !     !     pen   !     !     run   !     !     -     -     -     -     -     stp   stp   !     !     pen   !     !     -     los   exi   det   -     stp   !     res   -     -
los      !     !     !     !     !     -     -     -     !     !     -     !     -     stp   stp   !     !     -     lau   -     -     -     exi   !     !     stp   !     los   -     -
exi      pen   !     -     -     -     !     !     -     -     -     -     -     -     -     -     !     !     pen   !     -     -     -     -     det   -     -     new   exi   -     -
fat      pen   !     -     -     -     !     !     -     -     -     -     -     -     -     -     !     !     pen   !     -     -     -     -     det   -     -     new   fat   -     -
stp      pen   !     -     -     -     -     -     -     -     -     -     -     -     -     -     !     !     pen   !     -     -     -     -     -     -     -     new   stp   -     -
det      !     !     -     !     !     !     !     -     -     -     -     -     -     stp   stp   !     !     pen   !     -     -     -     -     -     pen   stp   new   det   -     -
"""
#        START KEEP  DUE   READY NRDY  SPAWN SFAIL EXIT  HANG  STALL UNSTL RSTRT LIMIT STOP  SHUTD DOWN  SREF  OSTRT LSENT LCHD  LREF  LLOST MFAIL BEND  BSTRT RSTOP RENEW RULES REG   UNREG
REMOTE_ACTIONS = """
new      L     .     !     !     !     !     !     !     !     !     .     !     .     C     C     !     !     CL    !     !     !     .     C     .     .     C     .     .     .     .
del      !     !     L     !     !     !     !     !     !     !     .     !     .     C     C     !     !     CL    !     !     !     .     C     .     .     C     !     .     .     .
hel      !     !     !     L     .     !     !     !     !     !     .     !     .     C     C     !     !     CL    !     !     !     .     C     C     .     C     !     .     .     .
sta      !     !     !     !     !     .     .     !     !     !     .     .     .     !     !     !     !     .     !     !     !     !     !     .     .     !     !     .     .     .
pen      !     !     !     !     !     !     .     .     !     !     .     !     .     C     C     !     !     .     .     .     .     .     C     !     !     C     !     .     .     .
lau      !     !     !     !     !     .     .     .     !     !     .     !     .     B     C     !     !     .     !     .     .     .     C     !     !     C     !     .     .     .
run      !     !     !     !     !     .     !     .     K     K     .     K     .     B     B     !     !     .     !     .     .     .     C     B     .     B     !     .     .     .
hun      !     !     !     !     !     !     !     .     .     .     .     .     .     B     B     !     !     .     !     !     !     !     !     B     .     B     !     .     .     .
stl      !     !     !     !     !     !     !     .     K     .     .     .     .     B     B     !     !     .     !     !     !     !     !     B     .     B     !     .     .     .
sto      !     !     !     !     !     .     !     .     .     .     .     .     .     .     .     .     .     .     !     .     !     .     .     .     .     .     !     .     .     .
res      !     !     L     !     !     .     !     !     .     .     .     .     .     C     C     !     !     CL    !     !     .     .     C     C     .     C     !     .     .     .
los      !     !     !     !     !     .     .     .     !     !     .     !     .     C     C     !     !     .     .     .     .     .     C     !     !     C     !     .     .     .
exi      L     !     .     .     .     !     !     .     .     .     .     .     .     .     .     !     !     CL    !     .     .     .     .     C     .     .     .     .     .     .
fat      L     !     .     .     .     !     !     .     .     .     .     .     .     .     .     !     !     CL    !     .     .     .     .     C     .     .     .     .     .     .
stp      L     !     .     .     .     .     .     .     .     .     .     .     .     .     .     !     !     CL    !     .     .     .     .     .     .     .     .     .     .     .
det      !     !     .     !     !     !     !     .     .     .     .     .     .     C     C     !     !     CL    !     .     .     .     .     .     L     C     .     .     .     .
"""

# A required node of this machine: whatever ends it ends the launch.
#        START KEEP  DUE   READY NRDY  SPAWN SFAIL EXIT  HANG  STALL UNSTL RSTRT LIMIT STOP  SHUTD DOWN  SREF  OSTRT LSENT LCHD  LREF  LLOST MFAIL BEND  BSTRT RSTOP RENEW RULES REG   UNREG
REQUIRED_MATRIX = """
new      sta   stp   !     !     !     !     !     !     !     !     -     !     -     stp   stp   !     !     sta   !     !     !     -     exi   -     -     stp   new   new   -     -
del      !     !     sta   !     !     !     !     !     !     !     -     !     -     stp   stp   !     !     sta   !     !     !     -     exi   -     -     stp   !     del   -     -
hel      !     !     !     sta   exi   !     !     !     !     !     -     !     -     stp   stp   !     !     sta   !     !     !     -     exi   det   -     stp   !     hel   -     -
sta      !     !     !     !     !     run   exi   !     !     !     -     -     -     !     !     !     !     -     !     !     !     !     !     -     -     !     !     sta   -     -
pen      !     !     !     !     !     !     -     -     !     !     -     !     -     stp   stp   !     !     -     lau   -     -     -     exi   !     !     stp   !     pen   -     -
lau      !     !     !     !     !     run   exi   exi   !     !     -     !     -     sto   stp   !     !     -     !     lau   pen   los   exi   !     !     stp   !     lau   lau   -
run      !     !     !     !     !     run   !     exi   hun   stl   -     run   run   sto   sto   !     !     -     !     run   -     los   exi   sto   -     sto   !     run   run   -
hun      !     !     !     !     !     !     !     exi   -     -     -     -     -     sto   sto   !     !     -     !     !     !     !     !     sto   -     sto   !     hun   hun   -
stl      !     !     !     !     !     !     !     exi   hun   -     run   -     -     sto   sto   !     !     -     !     !     !     !     !     sto   -     sto   !     stl   stl   -
sto      !     !     !     !     !     -     !     sto   -     -     -     -     -     -     -     stp   run   -     !     -     !     stp   -     -     -     -     !     sto   sto   -
res      !     !     sta   !     !     run   !     !     -     -     -     -     -     stp   stp   !     !     sta   !     !     -     -     exi   det   -     stp   !     res   -     -
los      !     !     !     !     !     -     -     -     !     !     -     !     -     stp   stp   !     !     -     lau   -     -     -     exi   !     !     stp   !     los   -     -
exi      sta   !     -     -     -     !     !     -     -     -     -     -     -     -     -     !     !     sta   !     -     -     -     -     det   -     -     new   exi   -     -
fat      sta   !     -     -     -     !     !     -     -     -     -     -     -     -     -     !     !     sta   !     -     -     -     -     det   -     -     new   fat   -     -
stp      sta   !     -     -     -     -     -     -     -     -     -     -     -     -     -     !     !     sta   !     -     -     -     -     -     -     -     new   stp   -     -
det      !     !     -     !     !     !     !     -     -     -     -     -     -     stp   stp   !     !     sta   !     -     -     -     -     -     sta   stp   new   det   -     -
"""
#        START KEEP  DUE   READY NRDY  SPAWN SFAIL EXIT  HANG  STALL UNSTL RSTRT LIMIT STOP  SHUTD DOWN  SREF  OSTRT LSENT LCHD  LREF  LLOST MFAIL BEND  BSTRT RSTOP RENEW RULES REG   UNREG
REQUIRED_ACTIONS = """
new      S     .     !     !     !     !     !     !     !     !     .     !     .     C     C     !     !     CS    !     !     !     .     CE    .     .     C     .     .     .     .
del      !     !     S     !     !     !     !     !     !     !     .     !     .     C     C     !     !     CS    !     !     !     .     CE    .     .     C     !     .     .     .
hel      !     !     !     S     E     !     !     !     !     !     .     !     .     C     C     !     !     CS    !     !     !     .     CE    C     .     C     !     .     .     .
sta      !     !     !     !     !     .     E     !     !     !     .     .     .     !     !     !     !     .     !     !     !     !     !     .     .     !     !     .     .     .
pen      !     !     !     !     !     !     .     .     !     !     .     !     .     C     C     !     !     .     .     .     .     .     CE    !     !     C     !     .     .     .
lau      !     !     !     !     !     .     E     E     !     !     .     !     .     B     C     !     !     .     !     .     .     E     CE    !     !     C     !     .     .     .
run      !     !     !     !     !     .     !     E     K     K     .     K     .     B     B     !     !     .     !     .     .     E     CE    B     .     B     !     .     .     .
hun      !     !     !     !     !     !     !     E     .     .     .     .     .     B     B     !     !     .     !     !     !     !     !     B     .     B     !     .     .     .
stl      !     !     !     !     !     !     !     E     K     .     .     .     .     B     B     !     !     .     !     !     !     !     !     B     .     B     !     .     .     .
sto      !     !     !     !     !     .     !     .     .     .     .     .     .     .     .     .     .     .     !     .     !     .     .     .     .     .     !     .     .     .
res      !     !     S     !     !     .     !     !     .     .     .     .     .     C     C     !     !     CS    !     !     .     .     CE    C     .     C     !     .     .     .
los      !     !     !     !     !     .     .     .     !     !     .     !     .     C     C     !     !     .     .     .     .     .     CE    !     !     C     !     .     .     .
exi      S     !     .     .     .     !     !     .     .     .     .     .     .     .     .     !     !     CS    !     .     .     .     .     C     .     .     .     .     .     .
fat      S     !     .     .     .     !     !     .     .     .     .     .     .     .     .     !     !     CS    !     .     .     .     .     C     .     .     .     .     .     .
stp      S     !     .     .     .     .     .     .     .     .     .     .     .     .     .     !     !     CS    !     .     .     .     .     .     .     .     .     .     .     .
det      !     !     .     !     !     !     !     .     .     .     .     .     .     C     C     !     !     CS    !     .     .     .     .     .     S     C     .     .     .     .
"""
RULES = Rules(respawn=True)
TABLES = {"local": (RULES, MATRIX, ACTIONS),
          "remote": (Rules(respawn=True, remote=True, machine="m1", owned=False), REMOTE_MATRIX, REMOTE_ACTIONS),
          "required": (Rules(required=True), REQUIRED_MATRIX, REQUIRED_ACTIONS)}


def record_in(state: str, rules: Rules = RULES) -> Record:
    started = state not in (m.NEW, m.DELAYED, m.HELD, m.STARTING, m.PENDING, m.LAUNCHING)
    return Record("/n", "n-1", "localhost", rules, state=state, pid=1 if state in (m.RUNNING, m.HUNG, m.STALLED, m.STOPPING)
                  else None, spawn_count=1 if started else 0, started=0.0 if started else None)


def event(kind: str) -> Event:
    return Event(kind, pid=1, exit_code=1, over_limit=(("memory_limit", 1.0),), process="n-2", reason="why")


def _rows(text: str) -> list[list[str]]:
    rows = [line.split() for line in text.strip().splitlines()]
    for row in rows:
        assert len(row) == len(EVENTS) + 1, row[0]
    return rows


def cells():
    """(table, rules, state, event, the state after it, its actions) for every cell of every matrix."""
    for table, (rules, states, actions) in TABLES.items():
        for row, acts in zip(_rows(states), _rows(actions)):
            assert row[0] == acts[0]
            for kind, expected, codes in zip(EVENTS, row[1:], acts[1:]):
                yield table, rules, SHORT[row[0]], kind, expected, codes


def test_the_matrix_covers_every_state_and_event():
    for table, (_rules, states, actions) in TABLES.items():
        assert [r[0] for r in _rows(states)] == [r[0] for r in _rows(actions)] == list(SHORT), table
    assert {s for _, _, s, _, _, _ in cells()} == set(m.STATES)
    assert set(EVENTS) == set(m.EVENTS)


def test_every_pair_is_done_ignored_or_refused_and_only_one_of_them():
    pairs = {(s, k) for s in m.STATES for k in m.EVENTS}
    done, ignored, refused = set(m.TABLE), set(m.IGNORED), set(m.REFUSED)
    assert done | ignored | refused == pairs
    assert not (done & ignored or done & refused or ignored & refused)
    # what a matrix cell says of a pair agrees: "!" for the refused, "-" or a state for the others
    for _table, _rules, state, kind, expected, _codes in cells():
        assert (expected == "!") == ((state, kind) in refused), (state, kind)


@pytest.mark.parametrize("table,rules,state,kind,expected,codes", list(cells()),
                         ids=lambda x: x if isinstance(x, str) else "")
def test_every_state_and_event(table, rules, state, kind, expected, codes):
    before = record_in(state, rules)
    if expected == "!":
        assert codes == "!" and (state, kind) in m.REFUSED
        with pytest.raises(m.InvalidTransition):
            m.step(before, event(kind), 10.0)
        return
    after, actions = m.step(before, event(kind), 10.0)
    assert (state, kind) not in m.REFUSED
    if expected == "-":
        assert after is before and actions == [] and codes == "."
    else:
        assert after.state == SHORT[expected]
        assert [a.kind for a in actions] == [ACTION_CODES[c] for c in codes.strip(".")]


def test_a_first_start_waits_for_spawn_delay_then_for_its_conditions():
    rules = Rules(policy=NodePolicy(spawn_delay=2.0, wait_for=(("topic", "/scan"),)))
    r, actions = m.step(record_in(m.NEW, rules), Event(m.START), 5.0)
    assert (r.state, r.next_start, actions) == (m.DELAYED, 7.0, [Action(m.SCHEDULE, 2.0)])
    r, actions = m.step(r, Event(m.DUE), 7.0)
    assert (r.state, actions, r.reason) == (m.HELD, [Action(m.HOLD)], "waiting for topic:/scan")
    r, actions = m.step(r, Event(m.READY), 8.0)
    assert (r.state, actions) == (m.STARTING, [Action(m.SPAWN)])


def test_an_operator_stop_during_a_respawn_delay_keeps_it_stopped():
    r = record_in(m.RUNNING)
    r, actions = m.step(r, Event(m.PROCESS_EXITED, exit_code=3), 10.0)
    assert r.state == m.RESPAWNING and Action(m.SCHEDULE, m.restart.MIN_RESPAWN_INTERVAL_S) not in actions
    assert actions[-1].kind == m.SCHEDULE
    r, actions = m.step(r, Event(m.STOP), 10.01)
    assert (r.state, r.operator_stopped, r.reason, actions) == (m.STOPPED, True, "stopped by operator",
                                                                [Action(m.CANCEL)])
    # the timer that fired as it was cancelled starts nothing
    assert m.step(r, Event(m.DUE), 10.1) == (r, [])


def test_a_bound_node_is_stopped_with_its_partner_and_started_once_after_it():
    rules = Rules(respawn=False, policy=NodePolicy(bind_to="/manager", wait_for=(("node", "/manager"),)))
    r = record_in(m.RUNNING, rules)
    r, actions = m.step(r, Event(m.BOUND_ENDED, reason="its manager ended"), 10.0)
    assert (r.state, r.rebind, actions) == (m.STOPPING, True, [Action(m.BEGIN_STOP)])
    r, _ = m.step(r, Event(m.PROCESS_EXITED, exit_code=0), 10.1)
    r, actions = m.step(r, Event(m.DOWN), 10.2)
    assert (r.state, r.rebind, actions, m.PUBLIC[r.state]) == (m.DETACHED, False, [], "stopped")
    assert m.step(r, Event(m.BOUND_ENDED), 10.3) == (r, [])  # (down again before it came back: one start)
    # its partner runs again: it waits for it to register, then starts (whatever its own respawn says)
    r, actions = m.step(r, Event(m.BOUND_STARTED), 11.0)
    assert (r.state, actions) == (m.HELD, [Action(m.HOLD)])
    r, actions = m.step(r, Event(m.READY), 11.5)
    assert (r.state, actions) == (m.STARTING, [Action(m.SPAWN)])


def test_a_bound_node_waiting_for_its_own_respawn_waits_for_its_partner_instead():
    r = record_in(m.RESPAWNING)
    r, actions = m.step(r, Event(m.BOUND_ENDED, reason="its manager ended"), 10.0)
    assert (r.state, r.next_start, actions) == (m.DETACHED, None, [Action(m.CANCEL)])
    assert m.step(r, Event(m.DUE), 10.1) == (r, [])  # (its timer, fired as it was cancelled)
    # an operator's stop while it waits holds over its partner's start
    stopped, actions = m.step(r, Event(m.STOP), 10.2)
    assert (stopped.state, stopped.operator_stopped) == (m.STOPPED, True)
    assert m.step(stopped, Event(m.BOUND_STARTED), 11.0) == (stopped, [])
    # an operator stopping a node being stopped with its partner keeps it stopped
    r, _ = m.step(record_in(m.RUNNING), Event(m.BOUND_ENDED), 10.0)
    r, _ = m.step(r._replace(operator_stopped=True), Event(m.DOWN), 10.5)
    assert r.state == m.STOPPED


def test_a_link_cut_during_a_launch_call_queues_the_node_once():
    """The cut-link double launch: the session ends while its `launch` call is under way; the node is lost
    (queued for the next session) once, and the cancelled call's late words change nothing."""
    rules = Rules(remote=True, owned=False, machine="m1")
    r, actions = m.step(record_in(m.NEW, rules), Event(m.START), 0.0)
    assert (r.state, actions) == (m.PENDING, [Action(m.LAUNCH)])
    r, _ = m.step(r, Event(m.LAUNCH_SENT), 0.1)
    assert r.state == m.LAUNCHING
    r, actions = m.step(r, Event(m.LINK_LOST, reason="machine [m1] dropped"), 0.2)
    assert (r.state, actions, m.PUBLIC[r.state]) == (m.LOST, [], "exited")
    # what the cancelled call may still say: refused, or launched
    assert m.step(r, Event(m.LAUNCH_REFUSED), 0.3) == (r, [])
    assert m.step(r, Event(m.LAUNCHED, process="talker-1"), 0.3) == (r, [])
    assert m.step(r, Event(m.LINK_LOST), 0.3) == (r, [])
    # the next session takes it, as one launch
    r, _ = m.step(r, Event(m.LAUNCH_SENT), 1.0)
    r, _ = m.step(r, Event(m.SPAWNED, pid=7, process="talker-2"), 1.1)
    assert (r.state, r.pid, r.process, r.spawn_count, r.restarts) == (m.RUNNING, 7, "talker-2", 1, 0)


def test_a_required_node_that_exits_ends_the_launch_with_its_status():
    rules = Rules(required=True)
    r, actions = m.step(record_in(m.RUNNING, rules), Event(m.PROCESS_EXITED, exit_signal=9), 1.0)
    assert r.state == m.EXITED and actions == [Action(m.END_LAUNCH, status=128 + 9)]
    r, actions = m.step(record_in(m.STARTING, rules), Event(m.SPAWN_FAILED), 1.0)
    assert actions == [Action(m.END_LAUNCH, status=1)]
    remote = Rules(required=True, remote=True, owned=False)
    assert m.step(record_in(m.RUNNING, remote), Event(m.PROCESS_EXITED, exit_code=0), 1.0)[1] == [Action(m.END_LAUNCH)]


def test_fatal_after_too_many_failed_starts_and_an_operator_start_clears_the_count():
    rules = Rules(respawn=True, policy=NodePolicy(respawn_max_retries=1, on_fatal="shutdown"))
    r = record_in(m.RUNNING, rules)._replace(started=0.0)
    r, actions = m.step(r, Event(m.PROCESS_EXITED, exit_code=1), 0.1)  # a failed start (under respawn_min_uptime)
    assert (r.state, r.failures) == (m.RESPAWNING, 1)
    # what the restart policy decided, in words for the console
    assert actions[0].kind == m.NOTE and "(1 failed start in a row)" in actions[0].text
    r, _ = m.step(r, Event(m.DUE), 0.5)
    r, _ = m.step(r, Event(m.SPAWNED, pid=2), 0.5)
    r, actions = m.step(r, Event(m.PROCESS_EXITED, exit_code=1), 0.6)
    assert r.state == m.FATAL and r.failures == 2
    assert actions == [Action(m.NOTE, text="FATAL: failed 2 starts in a row (respawn_max_retries=1), not restarted"),
                       Action(m.END_LAUNCH, status=1)]
    r, actions = m.step(r, Event(m.OPERATOR_START), 5.0)
    assert (r.state, r.failures, actions) == (m.STARTING, 0, [Action(m.CANCEL), Action(m.SPAWN)])


def test_a_remote_node_its_child_respawns_is_not_the_parents_to_restart():
    rules = Rules(respawn=True, remote=True, owned=False)
    r, actions = m.step(record_in(m.RUNNING, rules), Event(m.PROCESS_EXITED, exit_code=1), 1.0)
    assert (r.state, actions) == (m.RESPAWNING, [])  # no timer: the child starts it again
    assert m.step(r, Event(m.LINK_LOST), 1.1)[0].state == m.LOST  # (as a running one: it was on the child)
    r, actions = m.step(r, Event(m.SPAWNED, pid=9, process="n-3"), 1.2)
    assert (r.state, r.pid, r.restarts, actions) == (m.RUNNING, 9, 1, [])


def test_a_reload_stops_a_changed_node_with_its_reason_and_renews_it_with_a_clean_slate():
    r = record_in(m.RUNNING)._replace(failures=2)
    r, actions = m.step(r, Event(m.RELOAD_STOP, reason="reload: args changed"), 1.0)
    assert r.state == m.STOPPING and actions == [Action(m.BEGIN_STOP)] and not r.operator_stopped
    r, _ = m.step(r, Event(m.DOWN, exit_code=0), 2.0)
    assert (r.state, r.reason) == (m.STOPPED, "reload: args changed")
    new_rules = Rules(respawn=False, policy=NodePolicy(respawn_max_retries=3))
    r, actions = m.step(r._replace(operator_stopped=True), Event(m.RENEW, rules=new_rules, reason="reload"), 3.0)
    assert (r.state, r.rules, r.failures, r.operator_stopped, actions) == (m.NEW, new_rules, 0, False, [])
    r, actions = m.step(r, Event(m.START), 3.0)
    assert r.state == m.STARTING and actions == [Action(m.SPAWN)]
    r, _ = m.step(r, Event(m.SPAWNED, pid=7), 3.1)
    assert (r.spawn_count, r.restarts) == (2, 1)  # (its runs go on counting: its log is appended to)


def test_new_rules_apply_where_the_node_stands():
    fatal = record_in(m.FATAL)
    r, actions = m.step(fatal, Event(m.RULES, rules=Rules(policy=NodePolicy(respawn_max_retries=9))), 1.0)
    assert r.state == m.FATAL and r.rules.policy.respawn_max_retries == 9 and actions == []
    # an operator-stopped node that a reload does not change stays stopped
    stopped = record_in(m.STOPPED)._replace(operator_stopped=True)
    r, _ = m.step(stopped, Event(m.RULES, rules=Rules()), 1.0)
    assert r.state == m.STOPPED and r.operator_stopped


def test_hang_and_limit_restart_kill_the_run_and_what_follows():
    r, actions = m.step(record_in(m.RUNNING), Event(m.HANG, reason="no answer"), 1.0)
    assert (r.state, actions) == (m.HUNG, [Action(m.KILL)])
    r, actions = m.step(record_in(m.RUNNING, Rules()), Event(m.RESTART, reason="over memory_limit"), 1.0)
    assert actions == [Action(m.KILL)] and m.step(r, Event(m.RESTART), 1.0) == (r, [])
    r, actions = m.step(r, Event(m.PROCESS_EXITED, exit_signal=9), 1.1)
    assert (r.state, actions) == (m.RESPAWNING, [Action(m.SCHEDULE, 0.0)])  # (not respawn="true": still again)


# ---- invariants over random event sequences ---------------------------------------------------------------

RULE_SETS = [Rules(), Rules(respawn=True), Rules(required=True),
             Rules(respawn=True, policy=NodePolicy(respawn_max_retries=2, spawn_delay=1.0)),
             Rules(respawn=True, remote=True, owned=False, machine="m1"),
             Rules(respawn=True, remote=True, owned=True, machine="m1",
                   policy=NodePolicy(respawn_max_retries=1, wait_for=(("node", "/a"),)))]
BY_ITSELF = [m.DUE, m.READY, m.NOT_READY, m.SPAWNED, m.SPAWN_FAILED, m.PROCESS_EXITED, m.HANG, m.RESTART, m.LIMIT,
             m.DOWN, m.STOP_REFUSED, m.LAUNCH_SENT, m.LAUNCHED, m.LAUNCH_REFUSED, m.LINK_LOST, m.MACHINE_FAILED,
             m.SHUTDOWN]
STARTS = (m.SPAWN, m.LAUNCH)


@settings(max_examples=300, deadline=None)
@given(rules=st.sampled_from(RULE_SETS), kinds=st.lists(st.sampled_from(EVENTS), max_size=40),
       codes=st.lists(st.integers(-9, 3), min_size=40, max_size=40))
def test_invariants(rules, kinds, codes):
    """A stopped node never starts by itself, a FATAL one only by an operator; every state has a public name;
    counts never go down; a transition not in the table raises, and changes nothing."""
    r = Record("/n", "n-1", "host", rules)
    now = 0.0
    for kind, code in zip(kinds, codes):
        now += 0.3
        e = Event(kind, pid=100 + int(now * 10), exit_code=code if code >= 0 else None,
                  exit_signal=-code if code < 0 else None, process="n-%d" % int(now * 10))
        try:
            new, actions = m.step(r, e, now)
        except m.InvalidTransition:
            continue
        assert new.state in m.PUBLIC
        assert new.spawn_count >= r.spawn_count and new.restarts >= r.restarts
        starts = any(a.kind in STARTS for a in actions)
        if r.state in (m.STOPPED, m.FATAL) and kind in BY_ITSELF:
            assert not starts and new.state in (m.STOPPED, m.FATAL), (r, e, new)
        # (START from a stopped state is the launch starting it anew: a remote child's parent does)
        if r.state == m.STOPPED and r.operator_stopped and kind not in (m.OPERATOR_START, m.START, m.RENEW):
            assert new.state == m.STOPPED
        r = new


def test_one_record_per_node_in_a_fleet():
    from launcher.fleet.state import Fleet
    fleet = Fleet()
    first = fleet.add("/a", process="a-1")
    assert fleet.add("/a", process="a-2") is first and list(fleet.records) == ["/a"]


def test_the_change_stream_serves_a_long_poll():
    """A reader waiting for changes after the last one it saw wakes at the next change, gets it with the
    events file's fields, and a reader that asks too late is told its list is incomplete."""
    import asyncio

    from launcher.fleet import state

    async def main():
        fleet = state.Fleet(clock=lambda: 100.0)
        fleet.add("/a", process="a-1")
        fleet.apply("/a", Event(m.START))
        seen, complete = fleet.changes_since(0)
        assert complete and [c["phase"] for c in seen] == [m.STARTING]
        waiter = asyncio.ensure_future(fleet.wait_change(fleet.seq, 5.0))
        await asyncio.sleep(0)
        assert not waiter.done()
        fleet.apply("/a", Event(m.SPAWNED, pid=4))
        await asyncio.wait_for(waiter, 1.0)
        new, complete = fleet.changes_since(1)
        assert complete and [(c["seq"], c["state"], c["pid"]) for c in new] == [(2, "running", 4)]
        before = asyncio.get_running_loop().time()
        await fleet.wait_change(fleet.seq, 0.05)  # nothing new: back after the timeout
        assert asyncio.get_running_loop().time() - before >= 0.04
        # the run's own lines are in the stream too, numbered with the nodes' changes (the steps the file leaves
        # out: marked internal)
        waiter = asyncio.ensure_future(fleet.wait_change(fleet.seq, 5.0))
        await asyncio.sleep(0)
        fleet.run_event("master_restarted", reason="why")
        await asyncio.wait_for(waiter, 1.0)
        fleet.apply("/a", Event(m.STOP))
        fleet.apply("/a", Event(m.DOWN))
        served, _ = fleet.changes_since(0)
        assert [(c["seq"], c.get("state"), c.get("event"), c.get("internal", False)) for c in served] == [
            (1, "waiting", None, True), (2, "running", None, False), (3, None, "master_restarted", False),
            (4, "running", None, True), (5, "stopped", None, False)]
        fleet.changes.popleft()  # (the oldest dropped, as past CHANGES_KEPT)
        assert fleet.changes_since(0)[1] is False
    asyncio.run(main())


def test_the_events_file_ends_with_the_launchs_end(tmp_path):
    """Visible changes are written, internal steps are not, and the launch's end is the last line."""
    import json

    from launcher.fleet import state
    path = tmp_path / "events.jsonl"
    fleet = state.Fleet(str(path), clock=lambda: 1.0)
    fleet.add("/a", process="a-1")
    fleet.apply("/a", Event(m.START))  # new -> starting: not written
    fleet.apply("/a", Event(m.SPAWNED, pid=5))
    fleet.apply("/a", Event(m.SHUTDOWN))  # running -> stopping: not written
    fleet.apply("/a", Event(m.DOWN, exit_signal=2))
    fleet.launch_ended("stopped by SIGINT", 0)
    fleet.close()
    lines = [json.loads(line) for line in path.read_text().splitlines()]
    assert [(e.get("state"), e.get("phase")) for e in lines[:-1]] == [("running", "running"), ("stopped", "stopped")]
    assert lines[-1]["event"] == state.LAUNCH_ENDED and lines[-1]["reason"] == "stopped by SIGINT"
    # the long poll serves every change; those the file leaves out are marked internal
    served = [(c.get("phase", c.get("event")), c.get("internal", False)) for c in fleet.changes_since(0)[0]]
    assert served == [(m.STARTING, True), (m.RUNNING, False), (m.STOPPING, True), (m.STOPPED, False),
                      (state.LAUNCH_ENDED, False)]  # (the run's own line, as the file has it)


def test_a_registration_is_the_current_runs_and_goes_with_it():
    r = record_in(m.RUNNING)
    r, actions = m.step(r, Event(m.REGISTERED, uri="http://h:1/"), 10.0)
    assert (r.state, r.registered, r.uri, actions) == (m.RUNNING, True, "http://h:1/", [])
    assert m.step(r, Event(m.REGISTERED, uri="http://h:1/"), 10.1) == (r, [])  # (said twice: no change)
    # the registration of another URI going (an earlier run's, purged late) leaves this one
    assert m.step(r, Event(m.UNREGISTERED, uri="http://h:9/"), 10.2) == (r, [])
    gone, _ = m.step(r, Event(m.UNREGISTERED, uri="http://h:1/"), 10.3)
    assert (gone.registered, gone.uri) == (False, "")
    # a run that ends is registered no more; its next run is not until it registers in turn
    ended, _ = m.step(r, Event(m.PROCESS_EXITED, exit_code=1), 11.0)
    assert (ended.state, ended.registered, ended.uri) == (m.RESPAWNING, False, "")
    assert m.step(ended, Event(m.REGISTERED, uri="http://h:1/"), 11.1) == (ended, [])  # a late word: ignored
    again, _ = m.step(r._replace(state=m.RUNNING), Event(m.SPAWNED, pid=7), 12.0)
    assert (again.pid, again.registered, again.uri) == (7, False, "")
    stopped, _ = m.step(r._replace(state=m.STOPPING), Event(m.DOWN), 12.0)
    assert (stopped.state, stopped.registered) == (m.STOPPED, False)


def test_a_remote_run_may_register_before_its_child_says_it_runs():
    r = record_in(m.LAUNCHING, Rules(remote=True))
    r, _ = m.step(r, Event(m.REGISTERED, uri="http://other:1/"), 10.0)
    r, _ = m.step(r, Event(m.SPAWNED, pid=9, process="n-1"), 10.1)
    assert (r.state, r.registered, r.uri) == (m.RUNNING, True, "http://other:1/")
    lost, _ = m.step(r, Event(m.LINK_LOST, reason="cut"), 11.0)
    assert (lost.state, lost.registered) == (m.LOST, False)


def test_the_last_exit_is_kept_while_the_node_runs_again():
    """exit_code is the current run's (None while it runs); last_exit_* the last run that ended, with its time."""
    import time

    from launcher.fleet import state
    clock = [10.0]
    fleet = state.Fleet(clock=lambda: clock[0])
    fleet.add("/crasher", process="crasher-1", rules=Rules(respawn=True, respawn_delay=0.5))
    node = fleet.nodes["/crasher"]
    assert (node.last_exit_code, node.last_exit_signal, node.last_exit_at) == (None, None, None)
    fleet.apply("/crasher", Event(m.START))
    fleet.apply("/crasher", Event(m.SPAWNED, pid=5))
    before = time.time()
    fleet.apply("/crasher", Event(m.PROCESS_EXITED, exit_code=3))
    ended_at = node.last_exit_at
    assert before <= ended_at <= time.time() and (node.exit_code, node.last_exit_code) == (3, 3)
    clock[0] = 11.0
    fleet.apply("/crasher", Event(m.DUE))
    fleet.apply("/crasher", Event(m.SPAWNED, pid=6))
    d = node.as_dict()
    assert (d["state"], d["exit_code"], d["last_exit_code"], d["last_exit_signal"], d["last_exit_at"]) == (
        "running", None, 3, None, ended_at)
    fleet.apply("/crasher", Event(m.STOP))
    fleet.apply("/crasher", Event(m.PROCESS_EXITED, exit_signal=2))  # (its end while being stopped)
    fleet.apply("/crasher", Event(m.DOWN))
    d = node.as_dict()
    assert (d["state"], d["exit_signal"], d["last_exit_code"], d["last_exit_signal"]) == ("stopped", 2, None, 2)
    assert d["last_exit_at"] > ended_at
