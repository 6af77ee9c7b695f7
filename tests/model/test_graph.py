"""The run's graph: each registration's coming and going told once, a master's whole answer told as its
differences, and our master's registry as its writer (registrations, a bump, the last publisher gone)."""

from __future__ import annotations

from launcher.master import registry as reg
from launcher.model.graph import NODE, SERVICE, TOPIC, Graph, GraphChange


def told(graph: Graph) -> list[GraphChange]:
    changes: list[GraphChange] = []
    graph.listeners.append(changes.append)
    return changes


def test_a_change_is_told_once_and_a_whole_answer_as_its_differences():
    g = Graph()
    changes = told(g)
    g.node("/a", "http://h:1/")
    g.node("/a", "http://h:1/")  # (the same: nothing new)
    g.key(TOPIC, "/scan", True)
    g.replace({"/a": "http://h:2/", "/b": "http://h:3/"}, ["/scan", "/map"], ["/srv"])
    g.replace({"/b": "http://h:3/"}, None, [])
    assert changes == [GraphChange(NODE, "/a", True, "http://h:1/"), GraphChange(TOPIC, "/scan", True),
                       GraphChange(NODE, "/a", True, "http://h:2/"), GraphChange(NODE, "/b", True, "http://h:3/"),
                       GraphChange(TOPIC, "/map", True), GraphChange(SERVICE, "/srv", True),
                       GraphChange(NODE, "/a", False, "http://h:2/"), GraphChange(SERVICE, "/srv", False)]
    assert g.has(TOPIC, "/map") and g.has(NODE, "/b") and not g.has(SERVICE, "/srv")
    g.clear()
    assert (g.nodes, g.topics, g.services) == ({}, set(), set())


def test_what_readers_want_is_the_union_of_theirs():
    g = Graph()
    one, two = object(), object()
    g.want(one, {(TOPIC, "/scan")})
    g.want(two, {(NODE, "/amcl"), (TOPIC, "/scan")})
    assert g.wanted == {(TOPIC, "/scan"), (NODE, "/amcl")}
    g.want(two, set())
    assert g.wanted == {(TOPIC, "/scan")}


def test_a_readers_error_is_said_and_the_others_are_told():
    g = Graph()
    said: list[str] = []
    g.warn = said.append
    g.listeners.append(lambda c: 1 / 0)
    changes = told(g)
    g.node("/a", "http://h:1/")
    assert len(changes) == 1 and "ZeroDivisionError" in said[0]


def test_our_registry_tells_the_graph():
    g = Graph()
    changes = told(g)
    bumped = []
    r = reg.Registry(lambda old, caller: bumped.append(old.api), graph=g)
    r.register(reg.PUBLICATIONS, "/chatter", "/talker", "http://h:1/")
    r.register(reg.PUBLICATIONS, "/chatter", "/other", "http://h:2/")  # (a second publisher: no news)
    r.register(reg.SERVICES, "/srv", "/talker", "http://h:1/", "rosrpc://h:9")
    r.register(reg.SUBSCRIPTIONS, "/chatter", "/talker", "http://h:3/")  # the same name, a new process
    r.unregister(reg.PUBLICATIONS, "/chatter", "/other", "http://h:2/")  # the last publisher goes
    r.unregister(reg.SUBSCRIPTIONS, "/chatter", "/talker", "http://h:3/")  # /talker's last registration
    assert bumped == ["http://h:1/"]
    assert changes == [GraphChange(NODE, "/talker", True, "http://h:1/"), GraphChange(TOPIC, "/chatter", True),
                       GraphChange(NODE, "/other", True, "http://h:2/"), GraphChange(SERVICE, "/srv", True),
                       GraphChange(SERVICE, "/srv", False), GraphChange(NODE, "/talker", True, "http://h:3/"),
                       GraphChange(TOPIC, "/chatter", False), GraphChange(NODE, "/other", False, "http://h:2/"),
                       GraphChange(NODE, "/talker", False, "http://h:3/")]
