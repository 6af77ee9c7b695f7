"""plan/diff: the difference of two plans as a pure function (no process, no master)."""

from __future__ import annotations

import pytest

from launcher.model.config import LaunchConfig, Machine, Node, NodePolicy, Param
from launcher.plan.diff import Difference, NodeChange, difference, lines, same_value
from launcher.xml import load


def config(*nodes: Node, params: dict | None = None, machines: dict | None = None) -> LaunchConfig:
    return LaunchConfig(nodes=tuple(nodes), params={k: Param(k, v, "f.launch", 1) for k, v in (params or {}).items()},
                        machines=machines or {})


A = Node("pkg", "exe", "a", line=3)
B = Node("pkg", "exe", "b", line=4)


def names(changes) -> list[str]:
    return [c.name for c in changes]


def test_nothing_changed_is_empty():
    c = config(A, B, params={"/g": 1, "/a/rate": 2.0})
    d = difference(c, config(A, B, params={"/g": 1, "/a/rate": 2.0}))
    assert d == Difference() and d.empty and list(lines(d)) == []


def test_where_a_node_is_declared_is_no_change():
    assert difference(config(A), config(A._replace(filename="other.launch", line=99))).empty


def test_a_changed_private_param_restarts_only_its_owner():
    d = difference(config(A, B, params={"/a/rate": 1, "/b/rate": 1}), config(A, B, params={"/a/rate": 2, "/b/rate": 1}))
    assert d.set == (("/a/rate", 2),) and d.delete == ()
    assert names(d.restart) == ["/a"] and "parameter /a/rate changed 1 -> 2" in d.restart[0].why
    assert d.start == d.stop == d.supervise == ()


def test_a_deep_private_param_belongs_to_the_nearest_node():
    ab = Node("pkg", "exe", "b", namespace="/a/")
    d = difference(config(A, ab, params={"/a/b/x/y": 1}), config(A, ab, params={"/a/b/x/y": 2}))
    assert names(d.restart) == ["/a/b"]


def test_a_global_param_is_set_and_nothing_restarts():
    d = difference(config(A, params={"/g": 1}), config(A, params={"/g": 2, "/h": "new"}))
    assert d.set == (("/g", 2), ("/h", "new")) and d.restart == ()


def test_a_param_of_another_type_is_a_change():
    for old, new in ((1, 1.0), (1, True), ("1", 1), ([1], [1.0]), ({"a": 1}, {"a": True})):
        assert difference(config(params={"/p": old}), config(params={"/p": new})).set == (("/p", new),)
    assert same_value({"a": [1, {"b": "c"}]}, {"a": [1, {"b": "c"}]})


def test_a_param_no_longer_set_is_deleted_and_its_owner_restarts():
    d = difference(config(A, params={"/g": 1, "/a/x": 1}), config(A))
    assert d.delete == ("/g", "/a/x") and names(d.restart) == ["/a"] and "deleted" in d.restart[0].why


def test_run_id_and_roslaunch_uris_are_never_touched():
    old = config(params={"/run_id": "x", "/roslaunch/uris/host_a__1": "u"})
    assert difference(old, config()).empty
    assert difference(config(), old).empty


def test_added_and_removed_nodes():
    d = difference(config(A), config(B))
    assert d.stop == (NodeChange("/a", "removed from the launch"),)
    assert d.start == (NodeChange("/b", "new in the launch"),)
    assert d.restart == ()


def test_a_removed_nodes_params_are_deleted_without_restarting_anything():
    d = difference(config(A, B, params={"/b/x": 1}), config(A))
    assert d.delete == ("/b/x",) and names(d.stop) == ["/b"] and d.restart == ()


@pytest.mark.parametrize("field,value", [
    ("args", "--rate 5"), ("remap_args", (("chatter", "talk"),)), ("env_args", (("X", "1"),)), ("output", "screen"),
    ("cwd", "node"), ("launch_prefix", "nice"), ("machine_name", "m2"), ("type", "other"), ("package", "p2")])
def test_a_process_change_restarts_the_node_with_why(field, value):
    d = difference(config(A, B), config(A._replace(**{field: value}), B))
    assert names(d.restart) == ["/a"] and d.restart[0].why.startswith(field + " ")
    assert d.supervise == () and d.set == ()


def test_a_changed_executable_restarts_the_node():
    old = {"/a": "/ws1/pkg/exe", "/b": "/ws1/pkg/exe"}
    new = {"/a": "/ws2/pkg/exe", "/b": "/ws1/pkg/exe"}
    d = difference(config(A, B), config(A, B), old, new)
    assert names(d.restart) == ["/a"] and d.restart[0].why == "executable '/ws1/pkg/exe' -> '/ws2/pkg/exe'"


def test_a_changed_machine_restarts_its_nodes():
    m1 = Machine("m", "host1", filename="a", line=1)
    a = A._replace(machine_name="m")
    d = difference(config(a, machines={"m": m1}), config(a, machines={"m": m1._replace(address="host2")}))
    assert names(d.restart) == ["/a"] and "machine m changed" in d.restart[0].why
    assert difference(config(a, machines={"m": m1}), config(a, machines={"m": m1._replace(line=7)})).empty


@pytest.mark.parametrize("change", [
    {"respawn": True}, {"respawn_delay": 3.0}, {"required": True},
    {"policy": NodePolicy(respawn_max_retries=5)}, {"policy": NodePolicy(memory_limit=10 ** 9)}])
def test_supervision_changes_apply_without_a_restart(change):
    d = difference(config(A._replace(policy=NodePolicy(respawn_max_retries=3))),
                   config(A._replace(policy=NodePolicy(respawn_max_retries=3))._replace(**change)))
    assert d.restart == () and names(d.supervise) == ["/a"]


def test_a_process_change_with_a_supervision_change_is_a_restart_only():
    d = difference(config(A), config(A._replace(args="x", respawn=True)))
    assert names(d.restart) == ["/a"] and d.supervise == ()


def test_the_words_and_json():
    d = difference(config(A, params={"/old": 1}), config(A._replace(args="x"), B, params={"/g": [1, 2]}))
    assert list(lines(d)) == ["delete parameter /old", "set parameter /g = [1, 2]", "restart /a: args '' -> 'x'",
                              "start /b: new in the launch"]
    assert d.as_dict() == {"delete": ["/old"], "set": {"/g": [1, 2]}, "stop": {}, "restart": {"/a": "args '' -> 'x'"},
                           "start": {"/b": "new in the launch"}, "supervise": {}}


def test_loaded_files_rosparam_yaml_edit_restarts_the_node_it_loads_into(tmp_path):
    (tmp_path / "g.yaml").write_text("gains: {p: 1, i: 2}\n")
    launch = tmp_path / "a.launch"
    launch.write_text("""<launch>
  <param name="top" value="1"/>
  <node pkg="rospy_tutorials" type="talker" name="talker"><rosparam file="$(dirname)/g.yaml"/></node>
  <node pkg="rospy_tutorials" type="listener" name="listener"/>
  <group ns="ctl"><rosparam file="$(dirname)/g.yaml"/></group>
</launch>""")
    old = load([str(launch)], [], core=False)
    (tmp_path / "g.yaml").write_text("gains: {p: 1, i: 3}\n")
    new = load([str(launch)], [], core=False)
    d = difference(old, new)
    assert d.set == (("/talker/gains/i", 3), ("/ctl/gains/i", 3))
    assert names(d.restart) == ["/talker"]


def test_an_if_branch_switched_by_an_arg(tmp_path):
    launch = tmp_path / "a.launch"
    launch.write_text("""<launch><arg name="sim" default="true"/>
  <node if="$(arg sim)" pkg="rospy_tutorials" type="talker" name="sim_talker"/>
  <node unless="$(arg sim)" pkg="rospy_tutorials" type="talker" name="real_talker"/>
  <param name="use_sim_time" value="$(arg sim)"/>
</launch>""")
    d = difference(load([str(launch)], [], core=False), load([str(launch)], ["sim:=false"], core=False))
    assert names(d.stop) == ["/sim_talker"] and names(d.start) == ["/real_talker"]
    assert d.set == (("/use_sim_time", False),)


def test_anonymous_names_are_the_runs_own_on_a_reload(tmp_path):
    from launcher.model.names import AnonNames
    (tmp_path / "inc.launch").write_text('<launch><node pkg="rospy_tutorials" type="talker" name="$(anon t)"/></launch>')
    launch = tmp_path / "a.launch"
    launch.write_text("""<launch>
  <node pkg="rospy_tutorials" type="talker" name="$(anon t)"><param name="p" value="$(anon t)"/></node>
  <include file="$(dirname)/inc.launch"/>
</launch>""")
    anon = AnonNames()
    first = load([str(launch)], [], core=False, anon_names=anon)
    again = load([str(launch)], [], core=False, anon_names=anon)
    assert len({n.name for n in first.nodes}) == 2  # (an included file's $(anon t) is its own, as roslaunch's)
    assert difference(first, again).empty
    # without the run's names, every load makes new ones: both nodes would be stopped and started
    d = difference(first, load([str(launch)], [], core=False))
    assert len(d.stop) == len(d.start) == 2


def test_a_remote_nodes_respawn_is_its_childs_unless_it_has_a_policy():
    r = A._replace(machine_name="m")
    # the child got respawn with the node: a change is a restart
    d = difference(config(r), config(r._replace(respawn=True)), remote=frozenset({"/a"}))
    assert names(d.restart) == ["/a"] and "child respawns it" in d.restart[0].why
    # with a NodePolicy the parent's restart policy is in charge: supervision only
    p = r._replace(policy=NodePolicy(respawn_max_retries=2))
    d = difference(config(p), config(p._replace(respawn=True)), remote=frozenset({"/a"}))
    assert d.restart == () and names(d.supervise) == ["/a"]
    # a policy added moves its restarts from the child to the parent
    d = difference(config(r), config(p), remote=frozenset({"/a"}))
    assert names(d.restart) == ["/a"] and "move" in d.restart[0].why
    # a local node: supervision only, either way
    assert names(difference(config(A), config(A._replace(respawn=True))).supervise) == ["/a"]


def test_a_param_command_runs_again_and_is_compared_like_any_value(tmp_path):
    (tmp_path / "v").write_text("1")
    launch = tmp_path / "a.launch"
    launch.write_text('<launch><param name="from_cmd" command="cat %s"/><param name="same" command="echo x"/></launch>'
                      % (tmp_path / "v"))
    old = load([str(launch)], [], core=False)
    assert difference(old, load([str(launch)], [], core=False)).empty
    (tmp_path / "v").write_text("2")
    assert difference(old, load([str(launch)], [], core=False)).set == (("/from_cmd", 2),)  # (typed as roslaunch does)
