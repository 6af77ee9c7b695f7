"""The Python API and the pytest fixture: a launch of real rospy nodes, waited for, and nothing of it left afterwards."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
import threading

import psutil
import pytest

from launcher.api import Launch, LaunchFailed
from helpers import ROOT, ROS_PATH, until
from running import RospyTalker, make_package, write_launch

pytestmark = pytest.mark.integration

TALKER = RospyTalker

LISTENER = """#!/usr/bin/env python3
import rospy
from std_msgs.msg import String
rospy.init_node("listener")
rospy.Subscriber("chatter", String, lambda m: None)
rospy.spin()
"""


@pytest.fixture
def demo(tmp_path, ros_env):
    make_package(str(tmp_path / "src"), "apidemo", {"talker.py": TALKER, "listener.py": LISTENER})
    launch_file = write_launch(str(tmp_path), '<node name="talker" pkg="apidemo" type="talker.py"/>\n'
                                              '<node name="listener" pkg="apidemo" type="listener.py"/>')
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    # Debian's python first: the nodes' `#!/usr/bin/env python3` must find rospy
    env.update(PATH=ROS_PATH + ":" + env.get("PATH", ""), ROS_PACKAGE_PATH=str(tmp_path / "src"),
               ROS_HOME=str(tmp_path / "home"), ROS_IP="127.0.0.1")
    return launch_file, env


def _listening(proc: psutil.Process) -> set:
    return {c.laddr for c in (proc.net_connections if hasattr(proc, "net_connections") else proc.connections)(kind="inet") if c.status == psutil.CONN_LISTEN}


def _port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(1)
        return s.connect_ex(("127.0.0.1", port)) == 0


def test_launch_context_leaves_no_thread_process_or_socket(demo):
    launch_file, env = demo
    me = psutil.Process()
    threads_before = set(threading.enumerate())
    children_before = {p.pid for p in me.children(recursive=True)}
    listening_before = _listening(me)
    with Launch(launch_file, env=env) as launch:
        publishers = launch.wait_for_publisher("/chatter", timeout=60)
        assert publishers == ["/talker"]
        launch.wait_for_nodes("/talker", "/listener", timeout=60)
        until(lambda: launch.status().get("/talker") == "running" and launch.status().get("/listener") == "running",
              30, what="both nodes running in status()")
        port = launch.port
        assert _port_open(port)
        launcher_proc = psutil.Process(launch.process.pid)
        family = [launcher_proc] + launcher_proc.children(recursive=True)
        assert len(family) >= 3  # the launcher, its two nodes (and its no-orphans guard)
    # nothing of it is left: no process (the launcher, its nodes), no thread here, no listening socket
    for p in family:
        assert not p.is_running() or p.status() == psutil.STATUS_ZOMBIE, p
    assert {p.pid for p in me.children(recursive=True)} == children_before
    assert set(threading.enumerate()) == threads_before
    assert _listening(me) == listening_before
    assert not _port_open(port)
    assert launch.process.returncode == 0
    assert "process[talker-2]: started" in launch.output()


def test_a_launch_that_fails_says_why(demo, tmp_path):
    _launch_file, env = demo
    bad = write_launch(str(tmp_path), '<node name="x" pkg="apidemo" type="talker.py" output="bogus"/>', "bad.launch")
    with pytest.raises(LaunchFailed, match="bad.launch"):
        with Launch(bad, env=env, start_timeout=30):
            pass


def test_pytest_fixture_runs_a_launch_in_a_plain_pytest_test(demo, tmp_path):
    launch_file, env = demo
    test_file = tmp_path / "test_user.py"
    test_file.write_text(textwrap.dedent('''
        import psutil

        def test_chatter(ros_launch):
            launch = ros_launch(%r)
            assert launch.wait_for_publisher("/chatter", timeout=60) == ["/talker"]
            launch.wait_for_nodes("/listener", timeout=60)
            global PIDS
            PIDS = [launch.process.pid] + [p.pid for p in psutil.Process(launch.process.pid).children(recursive=True)]

        def test_after():
            # the fixture stopped the launch of the test before: none of its processes is left
            assert PIDS and not any(psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE
                                    for p in PIDS)
    ''' % launch_file))
    env = dict(env, PYTHONPATH=ROOT)
    # the plugin is loaded through its pytest11 entry point, as in any project that installs launcher
    # (PYTHONPATH makes the entry point's module this tree's copy)
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(test_file)],
                          env=env, capture_output=True, text=True, timeout=300, cwd=str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "2 passed" in proc.stdout


def test_a_port_taken_before_the_launcher_binds_it_is_replaced(demo):
    launch_file, env = demo
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        launch = Launch(launch_file, env=env)
        launch.port = busy.getsockname()[1]  # as if another program took the free port just after we looked
        launch.master_uri = "http://127.0.0.1:%d/" % launch.port
        with launch:
            assert launch.port != busy.getsockname()[1]
            launch.wait_for_publisher("/chatter", timeout=60)
