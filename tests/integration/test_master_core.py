"""`launch --core` with real clients: Debian's rospy and roscpp nodes and the rosnode/rostopic/rosparam tools."""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import subprocess
import sys
import time
import xmlrpc.client

import pytest

from helpers import Procs, free_port, until
from running import master_up

pytestmark = pytest.mark.integration

RPC_DOWN = (OSError, xmlrpc.client.Error)  # while a master starts or stops, a call may fail: not yet


@pytest.fixture
def core(ros_env, tmp_path):
    """A running `launch --core` on a free port; yields (procs, master proxy, env, core process)."""
    port = free_port()
    env = dict(os.environ, PATH=ros_env["path"] + ":" + os.environ.get("PATH", ""),
               ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_HOME=str(tmp_path / "home"),
               ROS_LOG_DIR=str(tmp_path / "log"), ROS_IP="127.0.0.1", PYTHONPATH="")
    env.pop("ROS_HOSTNAME", None)
    procs = Procs(env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    launch_env = dict(env, PATH=os.environ.get("PATH", ""))  # our launch runs on this python
    p = procs.start([sys.executable, "-m", "launcher", "--core", "-p", str(port)], env=launch_env)
    master = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])
    until(lambda: master.getParam("/t", "/run_id")[0] == 1, 20, what="launch --core", errors=RPC_DOWN)
    try:
        yield procs, master, env, p
    finally:
        procs.stop_all()


def _rospy(procs, ros_env, code, *args):
    return procs.start([ros_env["python"], "-c", code, *args])


def _wait_line(proc, prefix, timeout=30.0):
    """The first output line of `proc` starting with prefix (fails on exit or time-out)."""
    deadline = time.monotonic() + timeout
    fd = proc.stdout.fileno()
    buf = getattr(proc, "_seen", "")
    while time.monotonic() < deadline:
        for line in buf.splitlines():
            if line.startswith(prefix):
                return line
        ready, _, _ = select.select([fd], [], [], 0.1)
        if ready:
            chunk = os.read(fd, 65536).decode(errors="replace")
            if not chunk:
                break
            buf += chunk
            proc._seen = buf
    raise AssertionError("no %r line from %s; output so far:\n%s" % (prefix, proc.args, buf[-2000:]))


TALKER = """
import rospy, sys
from std_msgs.msg import String
rospy.init_node('talker')
pub = rospy.Publisher('chatter', String, queue_size=10)
print('READY', flush=True)
r = rospy.Rate(20)
i = 0
while not rospy.is_shutdown():
    pub.publish(String(data='hello %d' % i)); i += 1
    try:
        r.sleep()
    except rospy.ROSInterruptException:
        break
print('SHUTDOWN', flush=True)
"""

LISTENER = """
import rospy
from std_msgs.msg import String
rospy.init_node('listener')
rospy.Subscriber('chatter', String, lambda m: print('HEARD', m.data, flush=True))
rospy.spin()
"""


def test_core_sets_roscore_parameters_and_tools_work(core, ros_env):
    procs, master, env, _ = core
    run_id = master.getParam("/t", "/run_id")[2]
    assert len(run_id) == 36
    # roscore's values are `rosversion` outputs, newline included
    version = procs.run(["rosversion", "roslaunch"]).stdout
    assert version.strip() and master.getParam("/t", "/rosversion")[2] == version
    out = procs.run(["rosparam", "get", "/rosversion"])
    assert out.returncode == 0 and version.strip() in out.stdout, out
    distro = master.getParam("/t", "/rosdistro")[2]
    assert distro == procs.run(["rosversion", "-d"]).stdout
    assert procs.run(["rosparam", "set", "/a/b", "{x: 1, y: [1, 2]}"]).returncode == 0
    out = procs.run(["rosparam", "get", "/a/b/y"])
    assert out.stdout.split() == ["-", "1", "-", "2"], out
    out = procs.run(["rosnode", "list"])
    assert out.returncode == 0, out


def test_rospy_talker_listener_through_our_master(core, ros_env):
    procs, master, env, _ = core
    listener = _rospy(procs, ros_env, LISTENER)
    talker = _rospy(procs, ros_env, TALKER)
    _wait_line(talker, "READY")
    assert _wait_line(listener, "HEARD hello").startswith("HEARD hello")
    out = procs.run(["rostopic", "echo", "-n", "1", "/chatter"])
    assert "data: \"hello" in out.stdout, out
    out = procs.run(["rostopic", "info", "/chatter"])
    assert "/talker" in out.stdout and "/listener" in out.stdout, out
    out = procs.run(["rosnode", "info", "/talker"])
    assert "/chatter [std_msgs/String]" in out.stdout, out


def test_duplicate_node_name_shuts_down_the_old_node(core, ros_env):
    procs, master, env, _ = core
    first = _rospy(procs, ros_env, TALKER)
    _wait_line(first, "READY")
    first_api = master.lookupNode("/t", "/talker")[2]
    second = _rospy(procs, ros_env, TALKER)
    _wait_line(second, "READY")
    first.wait(20)  # rospy exits when the master tells it a new node took its name
    assert master.lookupNode("/t", "/talker")[2] != first_api
    assert second.poll() is None


def test_rosnode_kill_and_cleanup(core, ros_env):
    procs, master, env, _ = core
    talker = _rospy(procs, ros_env, TALKER)
    _wait_line(talker, "READY")
    out = procs.run(["rosnode", "kill", "/talker"])
    assert out.returncode == 0, out
    talker.wait(20)
    # rospy unregisters through system.multicall on its way out
    until(lambda: master.lookupNode("/t", "/talker")[0] == -1, 20, what="/talker to unregister", errors=RPC_DOWN)


CPP_NODE = r"""
#include <ros/ros.h>
#include <std_msgs/String.h>
#include <cstdio>
int main(int argc, char** argv) {
  ros::init(argc, argv, "cpp_talker");
  ros::NodeHandle nh;
  nh.setParam("cpp/answer", 42);
  int v = 0; nh.getParam("cpp/answer", v);
  printf("PARAM %d\n", v); fflush(stdout);
  ros::Publisher p = nh.advertise<std_msgs::String>("chatter", 10);
  ros::Rate r(20);
  while (ros::ok()) { std_msgs::String m; m.data = "cpp"; p.publish(m); ros::spinOnce(); r.sleep(); }
  return 0;
}
"""


@pytest.fixture(scope="session")
def cpp_talker(ros_env, tmp_path_factory, ros_part_missing):
    if shutil.which("g++") is None:
        ros_part_missing("g++ not installed")
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "roscpp", "std_msgs"], capture_output=True, text=True)
    if flags.returncode != 0:
        flags = subprocess.run(["pkg-config", "--cflags", "--libs", "roscpp"], capture_output=True, text=True)
    if flags.returncode != 0:
        ros_part_missing("roscpp development files not found by pkg-config")
    d = tmp_path_factory.mktemp("cpp")
    src = d / "talker.cpp"
    src.write_text(CPP_NODE)
    exe = str(d / "cpp_talker")
    subprocess.run(["g++", "-O0", "-o", exe, str(src)] + flags.stdout.split(), check=True, capture_output=True)
    return exe


def test_roscpp_node_with_rospy_listener(core, ros_env, cpp_talker):
    procs, master, env, _ = core
    listener = _rospy(procs, ros_env, LISTENER)
    node = procs.start([cpp_talker])
    assert _wait_line(node, "PARAM") == "PARAM 42"
    assert _wait_line(listener, "HEARD cpp") == "HEARD cpp"
    assert master.getParam("/t", "/cpp/answer")[2] == 42


def test_second_core_on_a_busy_port_fails_clearly(core, ros_env):
    procs, master, env, _ = core
    port = env["ROS_MASTER_URI"].rsplit(":", 1)[1].strip("/")
    out = subprocess.run([sys.executable, "-m", "launcher", "--core", "-p", port], env=dict(env, PATH=os.environ["PATH"]),
                         capture_output=True, text=True, timeout=30)
    assert out.returncode == 1
    assert "already running" in out.stderr
    assert "Traceback" not in out.stderr
    assert master.getPid("/t")[0] == 1  # the first one is unharmed


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "shutdown"])
def test_core_stops_cleanly(core, ros_env, how):
    procs, master, env, p = core
    t0 = time.monotonic()
    if how == "shutdown":
        assert master.shutdown("/t", "test over") == [1, "shutdown", 0]
    else:
        os.kill(p.pid, getattr(signal, how))
    assert p.wait(10) == 0
    assert time.monotonic() - t0 < 5
    with pytest.raises(OSError):
        master.getPid("/t")


def test_pid_file_is_written_and_removed(ros_env, tmp_path):
    port = free_port()
    pid_fn = tmp_path / "core.pid"
    env = dict(os.environ, ROS_HOME=str(tmp_path), ROS_MASTER_URI="http://127.0.0.1:%d/" % port)
    p = subprocess.Popen([sys.executable, "-m", "launcher", "--core", "-p", str(port), "--pid", str(pid_fn)],
                         env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        until(lambda: pid_fn.exists() and pid_fn.read_text() == str(p.pid), 20, what="pid file", errors=RPC_DOWN)
        until(lambda: xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"]).getPid("/t")[2] == p.pid, 20, what="master",
              errors=RPC_DOWN)
    finally:
        os.killpg(p.pid, signal.SIGINT)
        assert p.wait(10) == 0
    assert not pid_fn.exists()


def test_core_logs_to_its_run_directory_as_roscore(tmp_path):
    """roscore's first line is where it logs; the run directory gets the launch log, master.log and `latest`."""
    port = free_port()
    out = tmp_path / "core.out"
    env = dict(os.environ, ROS_HOME=str(tmp_path / "home"))
    env.pop("ROS_LOG_DIR", None)
    with open(out, "wb") as f:
        proc = subprocess.Popen([sys.executable, "-m", "launcher", "--core", "-p", str(port)], env=env, stdout=f,
                                stderr=subprocess.STDOUT)
    try:
        until(lambda: master_up(port), 30, what="core up")
        first = out.read_text().splitlines()[0]
        m = re.match(r"\.\.\. logging to (\S+)/roslaunch-[^/]+-%d\.log$" % proc.pid, first)
        assert m, first
        run_dir = m.group(1)
        assert os.path.dirname(run_dir) == str(tmp_path / "home" / "log")
        assert os.path.realpath(tmp_path / "home" / "log" / "latest") == os.path.realpath(run_dir)
        assert os.path.exists(os.path.join(run_dir, "master.log"))
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
