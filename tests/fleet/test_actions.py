"""One interpreter of the node table's actions for both runners: every kind the table can return is a runner's
method or the fleet's own, in the actions' order; the supervisor and the remote parent both implement
ActionRunner."""

from __future__ import annotations

import ast
import inspect

import pytest

from launcher.fleet import lifecycle as m
from launcher.fleet import actions as runner
from launcher.fleet.lifecycle import Action


class Recorder:
    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *args: self.calls.append((name,) + args)


def test_every_action_the_node_table_returns_is_carried_out_by_a_runner_or_is_the_fleets():
    tree = ast.parse(open(m.__file__).read())
    kinds = {getattr(m, call.args[0].id) for call in ast.walk(tree) if isinstance(call, ast.Call)
             and isinstance(call.func, ast.Name) and call.func.id == "Action" and call.args}
    assert {m.SPAWN, m.LAUNCH, m.END_LAUNCH, m.BEGIN_STOP} <= kinds  # (the walk finds them)
    assert kinds <= set(runner.METHODS) | runner.NOT_A_RUNNERS
    assert not set(runner.METHODS) & runner.NOT_A_RUNNERS


def test_the_actions_are_carried_out_in_their_order_with_their_delay():
    rec = Recorder()
    runner.carry_out(rec, "node", [Action(m.CANCEL), Action(m.SPAWN), Action(m.NOTE, text="words"),
                                   Action(m.SCHEDULE, 2.5), Action(m.END_LAUNCH, status=1), Action(m.HOLD),
                                   Action(m.BEGIN_STOP), Action(m.KILL), Action(m.LAUNCH)])
    assert rec.calls == [("cancel", "node"), ("spawn", "node"), ("schedule", "node", 2.5), ("hold", "node"),
                         ("begin_stop", "node"), ("kill", "node"), ("launch", "node")]
    with pytest.raises(ValueError):
        runner.carry_out(rec, "node", [Action("teleport")])


def test_the_supervisor_and_the_remote_parent_are_runners():
    from launcher.process.supervisor import Supervisor
    from launcher.remote.parent import RemoteParent
    wanted = {name: inspect.signature(f) for name, f in vars(runner.ActionRunner).items()
              if callable(f) and not name.startswith("_")}
    assert set(wanted) == set(runner.METHODS.values())
    for cls in (Supervisor, RemoteParent):
        for name, signature in wanted.items():
            assert len(inspect.signature(getattr(cls, name)).parameters) == len(signature.parameters), (cls, name)
