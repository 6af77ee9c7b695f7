"""What the bag tests share: real rospy/roscpp talkers and listeners, our `bag` command, Debian's rosbag as the judge."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import xmlrpc.client

from helpers import ROOT, ROS_PATH, ROS_PYTHON
from running import compile_roscpp, ros_env

# A rospy publisher: once SUBS subscribers are connected, "PREFIX N" for N < COUNT (0: forever) at RATE Hz.
RospyTalker = """#!%s
import sys, rospy
from std_msgs.msg import String
topic, prefix, count, rate, subs = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
rospy.init_node("bag_talker", anonymous=True)
pub = rospy.Publisher(topic, String, queue_size=1000)
while not rospy.is_shutdown() and pub.get_num_connections() < subs:
    rospy.sleep(0.01)
r = rospy.Rate(rate)
n = 0
while not rospy.is_shutdown() and (count == 0 or n < count):
    pub.publish(String("%%s %%d" %% (prefix, n)))
    n += 1
    try:
        r.sleep()
    except rospy.ROSInterruptException:
        break
rospy.spin()
""" % ROS_PYTHON

# A rospy subscriber printing each std_msgs/String's data on a line.
RospyListener = """#!%s
import sys, rospy
from std_msgs.msg import String
rospy.init_node("bag_listener", anonymous=True)
def on(msg):
    sys.stdout.write(msg.data + "\\n")
    sys.stdout.flush()
rospy.Subscriber(sys.argv[1], String, on, queue_size=1000)
rospy.spin()
""" % ROS_PYTHON

# Debian's rosbag reading a bag: {"topics": {topic: [type, count]}, "messages": [[topic, data], ...]} in order.
_READ = """
import json, sys, rosbag
bag = rosbag.Bag(sys.argv[1])
info = bag.get_type_and_topic_info()
out = {"topics": {t: [v.msg_type, v.message_count] for t, v in info.topics.items()},
       "messages": [[t, getattr(m, "data", None)] for t, m, _ in bag.read_messages()]}
print(json.dumps(out))
"""


def debian_env(env: dict[str, str]) -> dict[str, str]:
    return dict(env, PATH=ROS_PATH + ":" + env.get("PATH", ""), PYTHONPATH="")


# A mount namespace of our own (as root, or as root of a user namespace otherwise).
MOUNT_NS = ["unshare", "-m"] if os.geteuid() == 0 else ["unshare", "-r", "-m"]


def mount_ns_missing() -> str | None:
    """Why no mount namespace can be made here, or None."""
    try:
        if subprocess.run(MOUNT_NS + ["true"], capture_output=True, timeout=30).returncode == 0:
            return None
    except OSError:
        pass
    return "no mount namespaces here (%s)" % " ".join(MOUNT_NS)


def graph_env(tmp: str, port: int) -> dict[str, str]:
    """The environment of the test's ROS graph on the master at `port`, Debian's tools first on PATH."""
    return debian_env(ros_env(tmp, port, ""))


def subscribers(env: dict[str, str], topic: str) -> list[str]:
    """The nodes the master lists as subscribers of `topic`."""
    _, _, (_, subs, _) = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"]).getSystemState("/test")
    return next((nodes for t, nodes in subs if t == topic), [])


def debian_read(bag: str, env: dict[str, str]) -> dict:
    out = subprocess.run([ROS_PYTHON, "-c", _READ, bag], env=debian_env(env), capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def bag_argv(*args: str) -> list[str]:
    """Our `bag` command, run from this checkout."""
    return [sys.executable, "-m", "launcher.bag", *args]


def our_env(env: dict[str, str]) -> dict[str, str]:
    return dict(env, PYTHONPATH=ROOT)


def talkers(tmp: str) -> dict[str, list[str]]:
    """argv prefixes of a rospy and a roscpp talker (append: topic prefix count rate subs)."""
    py = os.path.join(tmp, "rospy_talker")
    with open(py, "w") as f:
        f.write(RospyTalker)
    os.chmod(py, 0o755)
    return {"rospy": [py], "roscpp": [compile_roscpp("bag_talker.cpp", os.path.join(tmp, "roscpp_talker"))]}


def listeners(tmp: str) -> dict[str, list[str]]:
    """argv prefixes of a rospy and a roscpp listener (append: topic)."""
    py = os.path.join(tmp, "rospy_listener")
    with open(py, "w") as f:
        f.write(RospyListener)
    os.chmod(py, 0o755)
    return {"rospy": [py], "roscpp": [compile_roscpp("bag_listener.cpp", os.path.join(tmp, "roscpp_listener"))]}
