"""/diagnostics messages: what each node's state becomes, in the wire format rosbags (and rospy) read."""

from rosbags.typesys import Stores, get_typestore

from launcher.services import diagnostics
from launcher.model.config import NodePolicy
from launcher.fleet import lifecycle as m
from launcher.fleet.lifecycle import Event, Rules
from launcher.fleet.state import Fleet


def test_each_node_is_one_status_named_after_it():
    fleet = Fleet()
    fleet.add("/ok", process="ok-2")
    fleet.add("/again", rules=Rules(respawn=True))
    fleet.add("/broken", rules=Rules(respawn=True, policy=NodePolicy(respawn_max_retries=0)))
    fleet.add("/crashed")
    fleet.add("/done")
    for name, pid, end in (("/ok", 42, None), ("/again", 43, Event(m.PROCESS_EXITED, exit_signal=9)),
                           ("/broken", 44, Event(m.PROCESS_EXITED, exit_code=3)),
                           ("/crashed", 45, Event(m.PROCESS_EXITED, exit_code=1)),
                           ("/done", 46, Event(m.PROCESS_EXITED, exit_code=0))):
        assert fleet.apply(name, Event(m.START)) == [m.Action(m.SPAWN)]
        fleet.apply(name, Event(m.SPAWNED, pid=pid))
        if end is not None:
            fleet.apply(name, end)
    fleet.sample("/ok", 0.25, 1 << 20)
    assert [s.state for s in fleet] == ["running", "respawning", "fatal", "exited", "exited"]
    raw = diagnostics.serialize(fleet, 7, 1234.5)
    msg = get_typestore(Stores.ROS1_NOETIC).deserialize_ros1(raw, "diagnostic_msgs/msg/DiagnosticArray")
    assert msg.header.seq == 7 and msg.header.stamp.sec == 1234 and msg.header.stamp.nanosec == 500000000
    by_name = {s.name: s for s in msg.status}
    assert list(by_name) == ["/ok", "/again", "/broken", "/crashed", "/done"]
    assert [by_name[n].level for n in by_name] == [0, 1, 2, 2, 0]
    values = {kv.key: kv.value for kv in by_name["/ok"].values}
    assert values["pid"] == "42" and values["state"] == "running" and values["cpu"] == "0.250"
    assert values["rss"] == str(1 << 20)
    assert {kv.key: kv.value for kv in by_name["/again"].values}["exit_signal"] == "9"


def test_type_is_rosbags_diagnostic_array():
    definition, md5 = get_typestore(Stores.ROS1_NOETIC).generate_msgdef("diagnostic_msgs/msg/DiagnosticArray")
    mtype = diagnostics.topic_type()
    assert (mtype.name, mtype.md5sum, mtype.definition) == ("diagnostic_msgs/DiagnosticArray", md5, definition)


def test_nodes_the_master_cannot_reach_are_one_warn_status():
    from launcher.master.server import UnresponsiveNode
    fleet = Fleet()
    assert diagnostics.master_status([]) is None  # every node answers: no entry at all
    u = UnresponsiveNode(["/wedged"], "http://10.0.0.9:4242/", 3, 12.0, "timed out", 2)
    raw = diagnostics.serialize(fleet, 1, 5.0, [diagnostics.master_status([u])])
    msg = get_typestore(Stores.ROS1_NOETIC).deserialize_ros1(raw, "diagnostic_msgs/msg/DiagnosticArray")
    (status,) = msg.status
    assert (status.level, status.name) == (diagnostics.WARN, "/launcher/master")
    assert "1 node(s) do not answer" in status.message
    (kv,) = status.values
    assert kv.key == "http://10.0.0.9:4242/" and kv.value == "/wedged: 3 failed callbacks over 12 s (timed out), 2 waiting"
