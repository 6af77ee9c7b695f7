"""remote.handler: roslaunch's parent API as the children call it, told to the fleet through the parent."""

from __future__ import annotations

import pytest

from launcher.fleet import lifecycle as m
from launcher.fleet.state import Fleet
from launcher.model.config import Machine, Node
from launcher.net.xmlrpc import Fault
from launcher.remote import session as s
from launcher.remote.handler import ParentHandler
from launcher.remote.link import RemoteChild


class Parent:
    """A parent's children and fleet, recording what the handler tells it."""

    def __init__(self, fleet):
        self.fleet = fleet
        self.told = []
        self.state = m.RUNNING  # every node's (the child lives on: a node of it runs)
        machine = Machine("m1", "far", env_loader="env")
        self.children = {"far-0": RemoteChild("far-0", machine, [Node("p", "t", "talker", namespace="/ns/"),
                                                                Node("p", "t", "listener")], self)}

    def node_state(self, rn):
        return self.state

    def tell(self, rn, event):
        self.told.append((rn.name, event.kind, event.pid, event.exit_code, event.exit_signal, event.process))
        return []


def test_a_child_registers_by_its_name_and_is_listed():
    parent = Parent(None)
    api = ParentHandler(parent)
    assert api.call("register", ["nobody-9", "http://x:1/"]) == [-1, "unknown child [nobody-9]", 0]
    assert api.call("list_children", []) == [1, "roslaunch children", []]
    assert api.call("register", ["far-0", "http://far:4242/"]) == [1, "registered", 1]
    child = parent.children["far-0"]
    assert child.uri == "http://far:4242/" and child.registered.is_set()
    assert api.call("list_children", []) == [1, "roslaunch children", ["http://far:4242/"]]
    with pytest.raises(Fault) as e:
        api.call("launch", ["<launch/>"])
    assert "method [launch] is not supported" in e.value.faultString


def test_a_childs_start_line_and_death_are_the_nodes_events():
    parent = Parent(Fleet())
    api = ParentHandler(parent)
    assert api.call("log", ["far-0", 2, "process[ns/talker-3]: started with pid [4242]"]) == [1, "", 1]
    assert api.call("log", ["far-0", 2, "process[nobody-1]: started with pid [1]"]) == [1, "", 1]
    assert api.call("log", ["far-0", 8, "process[listener-1]: started with pid [7]"]) == [1, "", 1]  # an error
    assert api.call("process_died", ["ns/talker-3", -9]) == [1, "", 0]
    assert api.call("process_died", ["listener-2", 1]) == [1, "", 0]
    assert api.call("process_died", ["nobody-1", 1]) == [1, "", 0]
    assert parent.told == [("/ns/talker", m.SPAWNED, 4242, None, None, "ns/talker-3"),
                           ("/ns/talker", m.PROCESS_EXITED, None, None, 9, "ns/talker-3"),
                           ("/listener", m.PROCESS_EXITED, None, 1, None, "listener-2")]


def test_before_the_fleet_exists_nothing_is_told():
    parent = Parent(None)
    api = ParentHandler(parent)
    api.call("log", ["far-0", 2, "process[ns/talker-3]: started with pid [4242]"])
    api.call("process_died", ["ns/talker-3", 0])
    assert parent.told == []
    assert api.call("list_processes", []) == api.call("list_processes", [])  # (answers with no fleet)
    pid = api.call("get_pid", [])
    assert pid[0] == 1 and pid[2] > 0


def test_a_child_whose_last_node_died_takes_no_more_launch_calls():
    parent = Parent(Fleet())
    api = ParentHandler(parent)
    child = parent.children["far-0"]
    child.session = s.launched(s.accepting(s.started(s.Session())))
    api.call("process_died", ["listener-1", 0])  # (the talker runs on)
    assert child.accepting
    parent.state = m.EXITED
    api.call("process_died", ["ns/talker-1", 0])
    assert child.session.phase == s.ENDING and not child.accepting
