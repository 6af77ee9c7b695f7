"""plan.relations: who is bound to whom and who waits for whom among a machine's nodes, made once from their
policies (each node in the order given; a remote child's next `launch` call adds its nodes)."""

from __future__ import annotations

from launcher.model.config import NodePolicy
from launcher.plan.relations import Relations, joined, of, without


def bound_to(partner: str) -> NodePolicy:
    return NodePolicy(bind_to=partner, wait_for=(("node", partner),))


def test_the_relations_are_made_from_the_nodes_policies():
    rel = of([("/manager", NodePolicy()),
              ("/loader1", bound_to("/manager")),
              ("/loader2", bound_to("/manager")),
              ("/spawner", NodePolicy(wait_for=(("node", "/controllers"), ("node", "/controllers"),
                                               ("topic", "/manager"), ("output", "/manager:ready")))),
              ("/controllers", NodePolicy()),
              ("/self", NodePolicy(bind_to="/self", wait_for=(("node", "/self"),))),
              ("/lonely", bound_to("/elsewhere"))])  # (another machine's node, or none: its readers ask about theirs)
    assert rel.bound == {"/manager": ("/loader1", "/loader2"), "/elsewhere": ("/lonely",)}
    assert rel.partner == {"/loader1": "/manager", "/loader2": "/manager", "/lonely": "/elsewhere"}
    # stopped before: who waits for a node (by its name: a topic or an output condition is no order at a stop)
    assert rel.stop_before == {"/manager": ("/loader1", "/loader2"), "/controllers": ("/spawner",),
                               "/elsewhere": ("/lonely",)}
    assert of([]) == Relations() == Relations({}, {}, {})
    # one node at a time (as a fleet is given them): a node that asks for none changes nothing, copies nothing
    assert joined(rel, "/plain", NodePolicy(wait_for=(("topic", "/scan"),))) is rel
    more = joined(rel, "/loader3", bound_to("/manager"))
    assert more.bound["/manager"] == ("/loader1", "/loader2", "/loader3") and more.partner["/loader3"] == "/manager"
    assert rel.bound["/manager"] == ("/loader1", "/loader2")  # (the relations given are left as they were)


def test_the_relations_of_more_nodes_are_added_to_those_given():
    first = of([("/manager", NodePolicy()), ("/loader1", bound_to("/manager"))])
    more = of([("/loader2", bound_to("/manager")), ("/plain", None)], first)
    assert more.bound == {"/manager": ("/loader1", "/loader2")} and first.bound == {"/manager": ("/loader1",)}
    assert of([("/plain", None), ("/other", NodePolicy())], first) is first  # (none asked for: nothing copied)


def test_a_node_given_again_has_its_new_relations_only():
    """A remote child's parent renews /loader bound to /other now: its old relations go, the others' stay."""
    first = of([("/manager", NodePolicy()), ("/loader", bound_to("/manager")), ("/cam", bound_to("/manager")),
                ("/spawner", NodePolicy(wait_for=(("node", "/loader"),)))])
    again = of([("/loader", bound_to("/other"))], without(first, ["/loader"]))
    assert again.bound == {"/manager": ("/cam",), "/other": ("/loader",)}
    assert again.partner == {"/cam": "/manager", "/loader": "/other"}
    assert again.stop_before == {"/manager": ("/cam",), "/loader": ("/spawner",), "/other": ("/loader",)}
    plain = of([("/loader", NodePolicy())], without(first, ["/loader"]))  # (its bind_to taken away)
    assert "/loader" not in plain.partner and plain.bound == {"/manager": ("/cam",)}
    assert without(first, ["/manager", "/nobody"]) is first  # (none of their own: nothing copied)
