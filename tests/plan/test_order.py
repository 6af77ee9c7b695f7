"""Who waits for whom: a cycle of wait_for node:/bind_to is refused, naming every member's file and line."""

from __future__ import annotations

import pytest

from launcher.model.errors import LaunchError
from launcher.plan.order import check_cycles
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
