"""A launch file's `<node pkg="rosbag" type="record">` on a machine where no ROS is found: ours records, the bag is whole.

Debian's ROS is hidden in a mount namespace (package lookup always searches
/usr/share, so emptying PATH or PYTHONPATH would hide nothing): every
/usr/share/<pkg> with a package.xml, its /usr/lib/<pkg>, and Debian's python
packages get an empty tmpfs over them. The talker is a node of our own
(launcher.net), since rospy is hidden too. Debian's rosbag, outside the
namespace, then reads what was recorded.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys

import pytest
from rosbags.rosbag1 import Reader, Writer

from bagparts import MOUNT_NS, debian_read, mount_ns_missing
from helpers import ROOT, free_port, until
from running import make_package, ros_env as graph_environ

# A talker without ROS: our in-process node publishing std_msgs/String "hello N" at 20 Hz on chatter.
OurTalker = """#!%s
import asyncio, os, struct, sys
from launcher.net.slave import SlaveNode
from launcher.net.tcpros import TopicType

async def main():
    name = next((a.split(":=", 1)[1] for a in sys.argv if a.startswith("__name:=")), "talker")
    node = SlaveNode("/" + name, os.environ["ROS_MASTER_URI"], host="127.0.0.1")
    await node.start()
    pub = await node.advertise("/chatter", TopicType("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1",
                                                     "string data\\n"))
    n = 0
    while True:
        data = ("hello %%d" %% n).encode()
        pub.publish(struct.pack("<I", len(data)) + data)
        n += 1
        await asyncio.sleep(0.05)

asyncio.run(main())
""" % sys.executable

RECORD = """
<launch>
  <arg name="bag"/>
  <node pkg="bagdemo" type="talker" name="talker"/>
  <node pkg="rosbag" type="record" name="recorder" args="-O $(arg bag) --chunksize 1 /chatter"/>
</launch>
"""
FIND = '<launch><param name="where" value="$(find rosbag)"/></launch>\n'


def hide_ros_script() -> str:
    """sh that mounts an empty tmpfs over Debian's ROS, then runs its arguments."""
    hide = []
    for name in sorted(os.listdir("/usr/share")):
        if os.path.exists(os.path.join("/usr/share", name, "package.xml")):
            hide.append(os.path.join("/usr/share", name))
            if os.path.isdir(os.path.join("/usr/lib", name)):
                hide.append(os.path.join("/usr/lib", name))
    hide += [d for d in ("/usr/lib/python3/dist-packages", "/opt/ros") if os.path.isdir(d)]
    assert "/usr/share/rosbag" in hide
    return "".join("mount -t tmpfs none %s && " % d for d in hide) + 'exec "$@"'


@pytest.fixture
def no_ros(ros_part_missing):
    if mount_ns_missing():
        ros_part_missing(mount_ns_missing())
    return MOUNT_NS + ["sh", "-c", hide_ros_script(), "sh"]


def test_record_node_runs_ours_where_no_rosbag_is_found(tmp_path, no_ros, ros_env):
    port = free_port()
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "bagdemo", {"talker": OurTalker})
    env = dict(graph_environ(str(tmp_path), port, pkgs), PYTHONPATH=ROOT)
    launch = [sys.executable, "-m", "launcher"]
    (tmp_path / "find.launch").write_text(FIND)
    (tmp_path / "record.launch").write_text(RECORD)
    # first: in there, rosbag is not found
    found = subprocess.run(no_ros + launch + ["--dump-params", str(tmp_path / "find.launch")], env=env,
                           capture_output=True, text=True, timeout=60)
    assert found.returncode != 0 and "rosbag" in found.stderr, (found.stdout, found.stderr)
    bag = str(tmp_path / "run.bag")
    args = subprocess.run(no_ros + launch + ["--args", "/recorder", str(tmp_path / "record.launch"), "bag:=" + bag],
                          env=env, capture_output=True, text=True, timeout=60)
    assert args.returncode == 0 and "-m launcher.bag record -O %s" % bag in args.stdout, args
    out = open(str(tmp_path / "launch.out"), "w")
    proc = subprocess.Popen(no_ros + launch + ["-p", str(port), str(tmp_path / "record.launch"), "bag:=" + bag],
                            env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        until(lambda: os.path.getsize(bag + ".active") > 8192, 60, what="the recording growing", errors=(OSError,))
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(30) == 0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    log = open(str(tmp_path / "launch.out")).read()
    assert os.path.exists(bag) and not os.path.exists(bag + ".active"), log
    read = debian_read(bag, dict(os.environ))
    data = [d for _, d in read["messages"]]
    first = int(data[0].split()[1])
    assert len(data) > 10 and data == ["hello %d" % n for n in range(first, first + len(data))]
    assert read["topics"] == {"/chatter": ["std_msgs/String", len(data)]}


def test_demo_recorded_and_played_on_its_clock_without_ros(tmp_path, no_ros):
    home = tmp_path / "home"
    env = dict(os.environ, ROS_PACKAGE_PATH=os.path.join(ROOT, "examples"), ROS_HOME=str(home), PYTHONPATH=ROOT,
               ROS_MASTER_URI="http://127.0.0.1:%d/" % free_port())
    env.pop("ROS_LOG_DIR", None)
    launch = no_ros + [sys.executable, "-m", "launcher"]
    rec = subprocess.run(launch + [os.path.join(ROOT, "examples", "launch", "record_demo.launch"), "duration:=4"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert rec.returncode == 0, rec.stderr
    bag = home / "demo.bag"
    assert bag.exists() and not (home / "demo.bag.active").exists(), rec.stdout
    with Reader(bag) as reader:
        assert reader.topics["/diagnostics"].msgcount >= 3
        start, end = reader.start_time / 1e9, reader.end_time / 1e9
    play = subprocess.run(launch + [os.path.join(ROOT, "examples", "launch", "play_demo.launch")],
                          env=env, capture_output=True, text=True, timeout=120)
    assert play.returncode == 0, play.stderr
    told = [float(t) for t in re.findall(r"sim time (\d+\.\d+)", play.stdout)]
    # the watcher's clock is the recording's
    assert told and all(start - 0.01 <= t <= end + 0.01 for t in told), (start, end, play.stdout)


BROKEN = """
<launch>
  <arg name="bag"/>
  <node pkg="rosbag" type="play" name="player" output="screen" required="true" args="-q $(arg bag)"/>
</launch>
"""


def test_a_play_node_given_a_broken_bag_says_what_is_wrong(tmp_path, no_ros):
    """The same words as `launcher bag play` in a terminal: the bag and what is wrong where, no traceback."""
    bag = tmp_path / "cut.bag"
    writer = Writer(str(bag))
    writer.open()
    conn = writer.add_connection("/chatter", "std_msgs/msg/String", msgdef="string data\n",
                                 md5sum="992ce8a1687cec8c8bd883ec73ca41d1")
    for n in range(100):
        writer.write(conn, 10**18 + n * 10**7, b"\x05\x00\x00\x00hello")
    writer.close()
    data = bag.read_bytes()
    bag.write_bytes(data[:len(data) - 100])
    (tmp_path / "broken.launch").write_text(BROKEN)
    env = dict(os.environ, ROS_HOME=str(tmp_path / "home"), PYTHONPATH=ROOT,
               ROS_MASTER_URI="http://127.0.0.1:%d/" % free_port())
    env.pop("ROS_LOG_DIR", None)
    run = subprocess.run(no_ros + [sys.executable, "-m", "launcher", str(tmp_path / "broken.launch"), "bag:=%s" % bag],
                         env=env, capture_output=True, text=True, timeout=120)
    said = run.stdout + run.stderr
    assert "Traceback" not in said and run.returncode != 0, said
    assert "ERROR %s: truncated at byte %d: chunk info " % (bag, len(data) - 100) in said, said
