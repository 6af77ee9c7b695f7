"""Who waits for whom: a cycle of wait_for node:/bind_to is refused, naming every member's file and line."""

from __future__ import annotations

import pytest

from launcher.model.errors import LaunchError
from launcher.plan.order import bind_nodelets, check_cycles, nodelet_manager
from launcher.xml import load


def _load(tmp_path, body: str):
    f = tmp_path / "a.launch"
    f.write_text("<launch>\n%s</launch>\n" % body)
    return load([str(f)], []), str(f)


def test_a_cycle_names_each_member_with_its_file_and_line(tmp_path):
    config, f = _load(tmp_path, '<node pkg="p" type="t" name="a" wait_for="node:b"/>\n'
                                '<node pkg="p" type="t" name="b" bind_to="/a"/>\n')
    with pytest.raises(LaunchError) as e:
        check_cycles(config.nodes)
    assert str(e.value) == ("%s:2: nodes wait for each other in a cycle (wait_for node: / bind_to), so none could "
                            "start: /a -> /b -> /a (/a at %s:2; /b at %s:3)" % (f, f, f))


def test_a_chain_and_a_wait_for_a_node_of_no_launch_are_fine(tmp_path):
    config, _ = _load(tmp_path, '<node pkg="p" type="t" name="a" wait_for="node:/elsewhere"/>\n'
                                '<group ns="r"><node pkg="p" type="t" name="b" bind_to="/a"/>\n'
                                '<node pkg="p" type="t" name="c" bind_to="b"/></group>\n')
    check_cycles(config.nodes)
    b = config.nodes[1].policy
    assert (b.bind_to, b.wait_for) == ("/a", (("node", "/a"),))
    assert config.nodes[2].policy.wait_for == (("node", "/r/b"),)


def test_a_nodelet_loader_is_bound_to_its_manager_as_the_nodelet_tool_resolves_it(tmp_path):
    config, _ = _load(tmp_path, '<node pkg="nodelet" type="nodelet" name="manager" args="manager"/>\n'
                                '<group ns="cam">\n'
                                '  <node pkg="nodelet" type="nodelet" name="mgr" args="manager"/>\n'
                                '  <node pkg="nodelet" type="nodelet" name="rect" args="load image_proc/rectify mgr"/>\n'
                                '  <node pkg="nodelet" type="nodelet" name="up" args="load a/B /manager --no-bond"/>\n'
                                '  <node pkg="nodelet" type="nodelet" name="re" args="load a/B other">\n'
                                '    <remap from="other/load_nodelet" to="/manager/load_nodelet"/></node>\n'
                                '  <node pkg="nodelet" type="nodelet" name="ar" args="__name:=x load a/B o o/load_nodelet:=mgr/load_nodelet"/>\n'
                                '  <node pkg="nodelet" type="nodelet" name="sa" args="standalone image_proc/rectify"/>\n'
                                '  <node pkg="nodelet" type="nodelet" name="far" args="load a/B /elsewhere"/>\n'
                                '  <node pkg="nodelet" type="nodelet" name="own" args="load a/B mgr" bind_to="/manager"/>\n'
                                '</group>\n')
    assert [nodelet_manager(n) for n in config.nodes] == [None, None, "/cam/mgr", "/manager", "/manager",
                                                         "/cam/mgr", None, "/elsewhere", "/cam/mgr"]
    bound = bind_nodelets(config, lambda n: False)
    assert [(n.name, n.policy.bind_to, n.policy.wait_for) for n in bound.nodes if n.policy] == [
        ("rect", "/cam/mgr", (("node", "/cam/mgr"),)), ("up", "/manager", (("node", "/manager"),)),
        ("re", "/manager", (("node", "/manager"),)), ("ar", "/cam/mgr", (("node", "/cam/mgr"),)),
        ("own", "/manager", (("node", "/manager"),))]  # (a manager of no launch binds nothing; bind_to stands)
    # a manager on another machine is not bound to (its supervisor is not this one)
    assert bind_nodelets(config, lambda n: n.name == "mgr").nodes[2].policy is None


def test_a_loader_whose_manager_waits_for_it_is_a_cycle(tmp_path):
    config, f = _load(tmp_path, '<node pkg="nodelet" type="nodelet" name="m" args="manager" wait_for="node:l"/>\n'
                                '<node pkg="nodelet" type="nodelet" name="l" args="load a/B m"/>\n')
    with pytest.raises(LaunchError) as e:
        check_cycles(bind_nodelets(config, lambda n: False).nodes)
    assert "/m -> /l -> /m (/m at %s:2; /l at %s:3)" % (f, f) in str(e.value)


def test_an_output_condition_names_a_node_of_this_machine_and_joins_the_cycle_check(tmp_path):
    from launcher.plan.order import check_output_waits
    config, f = _load(tmp_path, '<node pkg="p" type="t" name="a" wait_for="output:b:\'ready to go\'"/>\n'
                                '<node pkg="p" type="t" name="b" wait_for="node:/a"/>\n')
    assert config.nodes[0].policy.wait_for == (("output", "/b:ready to go"),)
    with pytest.raises(LaunchError) as e:
        check_cycles(config.nodes)
    assert "/a -> /b -> /a" in str(e.value)
    config, f = _load(tmp_path, '<node pkg="p" type="t" name="a"/>\n'
                                '<node pkg="p" type="t" name="b" wait_for="output:a:x"/>\n'
                                '<node pkg="p" type="t" name="c" wait_for="output:/nobody:ready"/>\n')
    check_output_waits(config.nodes[:2], lambda n: False)
    with pytest.raises(LaunchError) as e:
        check_output_waits(config.nodes, lambda n: False)
    assert str(e.value) == ("%s:4: wait_for output:/nobody:ready: [/nobody] is no node of this launch; a node's "
                            "output is watched for the nodes of this machine only" % f)
    with pytest.raises(LaunchError) as e:
        check_output_waits(config.nodes[:2], lambda n: n.name == "a")
    assert "%s:3: wait_for output:/a:x: [/a] runs on another machine" % f in str(e.value)
    with pytest.raises(LaunchError) as e:
        check_output_waits(config.nodes[:2], lambda n: n.name == "b")
    assert "%s:3: wait_for output:/a:x: [/b] runs on another machine" % f in str(e.value)
