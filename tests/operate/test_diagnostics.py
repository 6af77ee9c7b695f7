"""/diagnostics messages: what each node's state becomes, in the wire format rosbags (and rospy) read."""

from rosbags.typesys import Stores, get_typestore

from launcher.operate import diagnostics
from launcher.process.state import Fleet


def test_each_node_is_one_status_named_after_it():
    fleet = Fleet()
    fleet.add("/ok", process="ok-2")
    fleet.change("/ok", "running", pid=42)
    fleet.sample("/ok", 0.25, 1 << 20)
    fleet.add("/again")
    fleet.change("/again", "running", pid=43)
    fleet.change("/again", "respawning", exit_signal=9, next_start=0)
    fleet.add("/broken")
    fleet.change("/broken", "running", pid=44)
    fleet.change("/broken", "fatal", exit_code=3)
    fleet.add("/crashed")
    fleet.change("/crashed", "exited", exit_code=1)
    fleet.add("/done")
    fleet.change("/done", "exited", exit_code=0)
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
