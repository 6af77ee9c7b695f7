"""The typed seams (fleet/runner.py, services/service.py, services/server.RunView): each class that stands behind a
Protocol has every member it names, methods with the Protocol's parameters. Nothing checks a Protocol at run time
(they are annotations), so this test is what keeps a runner or a service from drifting off its seam."""

from __future__ import annotations

import ast
import inspect
import textwrap
from typing import Protocol

import pytest

from launcher.fleet import runner
from launcher.health.readiness import Readiness
from launcher.plan.specs import ProcessSpec
from launcher.process.supervisor import NodeProcess, Supervisor
from launcher.remote import handler, link
from launcher.remote.link import RemoteNode
from launcher.remote.parent import RemoteParent
from launcher.rostest.runner import RostestMaster
from launcher.run.runtime import StopSignals
from launcher.services import server, service
from launcher.services.masterlink import LocalParams, MasterSession, RemoteParams
from launcher.services.masterwatch import MasterWatch
from launcher.services.metrics import MetricsServer
from launcher.services.nodeservice import NodeService
from launcher.services.servers import ApiServer, DiagnosticsService, LogDiskCheck, RosoutService, RunView


def _members(proto: type) -> dict[str, object]:
    """A Protocol's members, its bases' included: name -> its function or property (None: a data attribute)."""
    found: dict[str, object] = {}
    for klass in reversed(proto.__mro__):
        if klass in (object, Protocol) or not getattr(klass, "_is_protocol", False):
            continue
        found.update({name: None for name in klass.__dict__.get("__annotations__", {})})
        found.update({name: value for name, value in vars(klass).items()
                      if not name.startswith("_") and (inspect.isfunction(value) or isinstance(value, property))})
    return found


def _set_on_self(cls: type) -> set[str]:
    """The attributes a class's methods (its bases' too) assign on `self`, and its class-level names."""
    names = set()
    for klass in cls.__mro__:
        if klass is object:
            continue
        names.update(vars(klass))
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        for node in ast.walk(tree):
            targets = (node.targets if isinstance(node, ast.Assign) else [node.target]
                       if isinstance(node, (ast.AnnAssign, ast.AugAssign)) else [])
            for t in targets:
                for e in (t.elts if isinstance(t, ast.Tuple) else [t]):
                    if isinstance(e, ast.Attribute) and isinstance(e.value, ast.Name) and e.value.id == "self":
                        names.add(e.attr)
    return names


def _parameters(f: object) -> list[str]:
    params = list(inspect.signature(f).parameters)
    return params[1:] if params and params[0] == "self" else params


def _missing(proto: type, cls: type) -> list[str]:
    """What `cls` lacks of `proto`, in words (empty: it stands behind the seam)."""
    has = _set_on_self(cls)
    wrong = []
    for name, member in _members(proto).items():
        if name not in has:
            wrong.append("no %s" % name)
        elif inspect.isfunction(member):
            mine = inspect.getattr_static(cls, name)
            if isinstance(mine, staticmethod):
                mine = mine.__func__
            if not callable(mine):
                wrong.append("%s is no method" % name)
            elif inspect.iscoroutinefunction(member) != inspect.iscoroutinefunction(mine):
                wrong.append("%s: async in one, not in the other" % name)
            elif len(_parameters(mine)) != len(_parameters(member)):
                wrong.append("%s%s, not %s" % (name, inspect.signature(mine), inspect.signature(member)))
    return wrong


SEAMS = [
    (runner.Runner, Supervisor),
    (runner.ReadinessRunner, Supervisor),
    (runner.ReadinessRunner, RemoteParent),
    (runner.RunningNode, NodeProcess),
    (runner.HeldNode, RemoteNode),
    (link.Parent, RemoteParent),
    (handler.Parent, RemoteParent),
    (runner.NodeSpec, ProcessSpec),
    (service.MasterLink, MasterSession),
    (service.MasterLink, RostestMaster),
    (service.Params, LocalParams),
    (service.Params, RemoteParams),
    (service.RunNodes, NodeService),
    (service.PlainService, ApiServer),
    (service.PlainService, RosoutService),
    (service.PlainService, DiagnosticsService),
    (service.PlainService, LogDiskCheck),
    (service.PlainService, MetricsServer),
    (service.PlainService, MasterWatch),
    (server.RunView, RunView),
    (service.Signals, StopSignals),
]


@pytest.mark.parametrize("proto, cls", SEAMS, ids=["%s-%s" % (p.__name__, c.__name__) for p, c in SEAMS])
def test_each_class_stands_behind_its_seam(proto, cls):
    assert _missing(proto, cls) == []


def test_the_seam_check_sees_what_is_missing():
    """(the check can fail: a class without a member, with other parameters, or sync for async)"""
    class Half:
        def __init__(self):
            self.fleet = None

        def node(self, name, extra):
            return None

        def hung(self, proc, reason):
            return None

    wrong = _missing(runner.Runner, Half)
    assert "no stalled" in wrong and "no shutting_down" in wrong and any(w.startswith("node(") for w in wrong)
    assert "no fleet" not in wrong and not any(w.startswith("hung") for w in wrong)

    class SyncStop:
        def stop(self):
            return None

    assert _missing(service.Service, SyncStop) == ["stop: async in one, not in the other"]


def test_readiness_names_its_runner_by_the_seam():
    """(the watchers of health/ stand below the runners' packages: they name the Protocol, not the class)"""
    annotation = inspect.signature(Readiness.__init__).parameters["runner"].annotation
    assert annotation == "ReadinessRunner"
