"""Helpers for the `launch` run tests: scratch packages with real node scripts, a real master, a launcher process."""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import xmlrpc.client

from helpers import ROS_PATH, ROS_PYTHON, free_port, pid_alive, until

HERE = os.path.dirname(os.path.abspath(__file__))

PACKAGE_XML = ('<?xml version="1.0"?>\n<package format="2"><name>%s</name><version>0.0.1</version>'
               '<description>test nodes</description><maintainer email="t@example.com">t</maintainer>'
               '<license>BSD</license></package>\n')


# A rospy talker publishing "hello" on chatter at 20 Hz (run with Debian's python first on PATH).
RospyTalker = """#!/usr/bin/env python3
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("chatter", String, queue_size=10)
rate = rospy.Rate(20)
while not rospy.is_shutdown():
    pub.publish(String("hello"))
    try:
        rate.sleep()
    except rospy.ROSInterruptException:
        break
"""

# a rospy node slow to register: it sleeps argv[1] seconds, writes the wall time to $STAMPS/<argv[2]> just before
# init_node (where it registers) as argv[2], then spins
SlowSpinner = """#!%s
import os, sys, time, rospy
time.sleep(float(sys.argv[1]))
with open(os.path.join(os.environ["STAMPS"], sys.argv[2]), "w") as f:
    f.write(repr(time.time()))
rospy.init_node(sys.argv[2])
rospy.spin()
""" % ROS_PYTHON


def make_package(root: str, name: str, scripts: dict[str, str]) -> str:
    """A package dir with executable scripts (name -> source)."""
    pkg = os.path.join(root, name)
    os.makedirs(pkg, exist_ok=True)
    with open(os.path.join(pkg, "package.xml"), "w") as f:
        f.write(PACKAGE_XML % name)
    for script, source in scripts.items():
        path = os.path.join(pkg, script)
        with open(path, "w") as f:
            f.write(source)
        os.chmod(path, 0o755)
    return pkg


def compile_roscpp(source_name: str, dest: str, libs: tuple[str, ...] = ()) -> str:
    """Compile tests/integration/nodes/<source_name> against Debian's roscpp (cached by content), and `libs`
    (e.g. "-lgtest")."""
    src = os.path.join(HERE, "nodes", source_name)
    with open(src, "rb") as f:
        digest = hashlib.sha1(f.read()).hexdigest()[:12]
    cache = os.path.join(os.environ.get("TMPDIR", "/tmp"), "launcher-test-build")
    os.makedirs(cache, exist_ok=True)
    exe = os.path.join(cache, "%s-%s" % (os.path.splitext(source_name)[0], digest))
    if not os.path.exists(exe):
        try:
            flags = subprocess.check_output(["pkg-config", "--cflags", "--libs", "roscpp"], text=True).split()
        except (OSError, subprocess.CalledProcessError):  # no pkg-config: Debian's roscpp link line
            flags = ("-lroscpp -lboost_chrono -lboost_filesystem -lrosconsole -lrosconsole_log4cxx "
                     "-lrosconsole_backend_interface -llog4cxx -lboost_regex -lboost_system -lboost_thread "
                     "-lroscpp_serialization -lxmlrpcpp -lrostime -lcpp_common").split()
        made = "%s.%d.tmp" % (exe, os.getpid())  # (each test run its own: two suites may run at once)
        subprocess.run(["g++", "-O1", "-o", made, src] + flags + list(libs), check=True)
        os.replace(made, exe)
    shutil.copy2(exe, dest)
    return dest


def ros_env(tmp: str, port: int, package_path: str) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_HOME=os.path.join(tmp, "home"),
               ROS_LOG_DIR=os.path.join(tmp, "log"), ROS_PACKAGE_PATH=package_path, ROS_IP="127.0.0.1")
    env.pop("ROS_NAMESPACE", None)
    env.pop("ROS_HOSTNAME", None)
    return env


def master_proxy(port: int) -> xmlrpc.client.ServerProxy:
    return xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port)


def master_up(port: int) -> bool:
    try:
        return master_proxy(port).getPid("/test")[0] == 1
    except OSError:
        return False


def get_param(port: int, key: str):
    code, _msg, value = master_proxy(port).getParam("/test", key)
    return value if code == 1 else None


class RosMaster:
    """Debian's real rosmaster on a free port."""

    def __init__(self, tmp: str, port: int | None = None):
        self.port = port or free_port()
        env = dict(os.environ, PATH=ROS_PATH, ROS_HOME=os.path.join(tmp, "masterhome"))
        self.proc = subprocess.Popen(["rosmaster", "--core", "-p", str(self.port)], env=env,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        until(lambda: master_up(self.port), 20, what="rosmaster up")

    def stop(self) -> None:
        stop_group(self.proc, 10)


def stop_group(proc: subprocess.Popen, timeout: float) -> None:
    """Ctrl-C for a process started in a session of its own, then SIGKILL after `timeout` seconds."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


class Launcher:
    """`python -m launcher ...` with output captured to files (a full pipe never blocks it)."""

    def __init__(self, args: list[str], env: dict[str, str], tmp: str, ignore_sigint: bool = False):
        self.out_path = os.path.join(tmp, "launch-%d.out" % time.monotonic_ns())
        self.err_path = self.out_path[:-4] + ".err"
        self._out = open(self.out_path, "wb")
        self._err = open(self.err_path, "wb")
        preexec = None
        if ignore_sigint:  # as a background job of a non-interactive shell starts
            def preexec():
                signal.signal(signal.SIGINT, signal.SIG_IGN)
        self.proc = subprocess.Popen([sys.executable, "-m", "launcher"] + args, env=env, stdout=self._out,
                                     stderr=self._err, stdin=subprocess.DEVNULL, preexec_fn=preexec)
        self.pid = self.proc.pid

    @property
    def stdout(self) -> str:
        with open(self.out_path, errors="replace") as f:
            return f.read()

    @property
    def stderr(self) -> str:
        with open(self.err_path, errors="replace") as f:
            return f.read()

    def wait_output(self, pattern: str, timeout: float = 30.0, stream: str = "stdout") -> re.Match:
        def found():
            m = re.search(pattern, getattr(self, stream))
            if m is None and self.proc.poll() is not None:
                m = re.search(pattern, getattr(self, stream))
                if m is None:
                    raise AssertionError("launcher exited (%s) before %r appeared\nstdout:\n%s\nstderr:\n%s"
                                         % (self.proc.returncode, pattern, self.stdout, self.stderr))
            return m
        return until(found, timeout, what="%r in launcher %s" % (pattern, stream))

    def until(self, cond, timeout: float, what: str) -> object:
        """helpers.until, and when it fails the launcher's own output with the failure (what it said of why)."""
        try:
            return until(cond, timeout, what=what)
        except AssertionError as e:
            raise AssertionError("%s\nlauncher (exit %s) stdout, its end:\n%s\nstderr, its end:\n%s"
                                 % (e, self.proc.poll(), self.stdout[-6000:], self.stderr[-6000:])) from None

    def started_pids(self) -> dict[str, int]:
        """process name -> pid of its latest start."""
        return {m.group(1): int(m.group(2))
                for m in re.finditer(r"process\[([^\]]+)\]: started with pid \[(\d+)\]", self.stdout)}

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def wait(self, timeout: float = 30.0) -> int:
        return self.proc.wait(timeout)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._out.close()
        self._err.close()


def write_launch(tmp: str, body: str, name: str = "test.launch") -> str:
    path = os.path.join(tmp, name)
    with open(path, "w") as f:
        f.write('<?xml version="1.0"?>\n<launch>\n%s\n</launch>\n' % body)
    return path


def _command_lines():
    """(pid, argv) of every process this user can read, from /proc."""
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open("/proc/%s/cmdline" % entry, "rb") as f:
                yield int(entry), f.read().decode(errors="replace").split("\0")
        except OSError:
            continue


def kill_leftovers(log_dir: str) -> list[int]:
    """SIGKILL every process whose command line logs under `log_dir` (`__log:=...`): what a reference tool left
    behind (Debian's roslaunch, stopped while its master starts, can leave its rosmaster and rosout running);
    the pids."""
    killed = []
    for pid, argv in _command_lines():
        if any(a.startswith("__log:=" + log_dir) for a in argv):
            try:
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            except OSError:
                pass
    return killed


def node_processes(log_dir: str) -> dict[str, list[int]]:
    """The live node processes of a launch, found in /proc by the `__log:=` in `log_dir` its command lines carry:
    node name (`__name:=`) -> pids (two: a node running twice)."""
    found: dict[str, list[int]] = {}
    for pid, argv in _command_lines():
        names = [a[len("__name:="):] for a in argv if a.startswith("__name:=")]
        if names and any(a.startswith("__log:=" + log_dir) for a in argv) and pid_alive(pid):
            found.setdefault(names[0], []).append(pid)
    return found
