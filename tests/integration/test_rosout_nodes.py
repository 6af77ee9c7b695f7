"""The built-in rosout with real rospy/roscpp nodes, a real master and Debian's ROS tools."""

from __future__ import annotations

import asyncio
import os
import re
import socket
import subprocess
import threading
import xmlrpc.client
from collections.abc import Callable
from typing import Any

import pytest

from helpers import Procs, free_port, until
from running import master_up

pytestmark = pytest.mark.integration

# A roscpp node: logs "waiting" until /rosout_test/go is true (so rosout is surely connected),
# then either the four-level demo or `count` numbered lines at `rate` per second.
CPP_LOGGER = r"""
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <algorithm>
#include <cstdlib>
int main(int argc, char** argv) {
  ros::init(argc, argv, "cpp_logger");
  ros::NodeHandle nh;
  int count = argc > 1 ? atoi(argv[1]) : 0;
  double rate = argc > 2 ? atof(argv[2]) : 1000.0;
  bool go = false;
  while (ros::ok() && !(nh.getParam("/rosout_test/go", go) && go)) {
    ROS_INFO("waiting");
    ros::WallDuration(0.05).sleep();
  }
  if (count < 0) {
    // rosconsole turns bytes that are not UTF-8 into '?', but a node may publish any bytes on
    // /rosout itself; rosout.cpp writes them as they are.
    ros::Publisher pub = nh.advertise<rosgraph_msgs::Log>("/rosout", 10);
    while (ros::ok() && pub.getNumSubscribers() == 0) ros::WallDuration(0.01).sleep();
    rosgraph_msgs::Log raw;
    raw.header.stamp = ros::Time::now();
    raw.level = rosgraph_msgs::Log::INFO;
    raw.name = ros::this_node::getName();
    raw.msg = "raw \xff\xfe bytes";
    raw.file = "cpp_logger.cpp";
    raw.function = "main";
    raw.topics.push_back("/t\xfe");
    pub.publish(raw);
  } else if (count == 0) {
    ROS_INFO("hello info %d", 1);
    ROS_WARN("warn: two");
    ROS_ERROR("error three");
    ROS_FATAL("fatal four");
  } else {
    const int burst = std::max(1, (int)(rate / 100));
    ros::WallDuration tick(burst / rate);
    ros::WallTime next = ros::WallTime::now();
    for (int i = 0; i < count && ros::ok(); ++i) {
      ROS_INFO("load %d", i);
      if ((i + 1) % burst == 0) { next += tick; ros::WallTime::sleepUntil(next); }
    }
  }
  ROS_INFO("done");
  ros::waitForShutdown();
  return 0;
}
"""

PY_LOGGER = r"""
import sys, time, rospy
rospy.init_node("py_logger")
while not rospy.is_shutdown() and not rospy.get_param("/rosout_test/go", False):
    rospy.loginfo("waiting")
    time.sleep(0.05)
argv = rospy.myargv()
count = int(argv[1]) if len(argv) > 1 else 0
def main():
    if count == 0:
        rospy.loginfo("hello info %d", 1)
        rospy.logwarn("warn: two")
        rospy.logerr("error three")
        rospy.logfatal("fatal four")
    else:
        for i in range(count):
            rospy.loginfo("load %d", i)
            time.sleep(0.001)
    rospy.loginfo("done")
main()
rospy.spin()
"""


class RosoutThread:
    """Our Rosout running on its own asyncio loop in a thread, as the launcher would run it."""

    def __init__(self, master_uri: str, log_dir: str, **kw: Any):
        from launcher.net.rosout import Rosout
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.rosout = self._run(self._make(Rosout, master_uri, log_dir, kw))
        self._run(self.rosout.start())

    @staticmethod
    async def _make(cls: Any, master_uri: str, log_dir: str, kw: dict) -> Any:
        return cls(master_uri, log_dir, host="127.0.0.1", **kw)

    def _run(self, coro: Any, timeout: float = 30) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn: Callable[[], Any]) -> Any:
        async def wrapped() -> Any:
            return fn()
        return self._run(wrapped())

    def stop(self) -> None:
        if self.loop.is_running():
            self._run(self.rosout.stop())
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(10)


@pytest.fixture(scope="session")
def cpp_logger(ros_env, tmp_path_factory) -> str:
    """The roscpp logging node, compiled once per session."""
    build = tmp_path_factory.mktemp("cpp_logger")
    src = build / "cpp_logger.cpp"
    src.write_text(CPP_LOGGER)
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "roscpp"], capture_output=True,
                           text=True, check=True).stdout.split()
    exe = str(build / "cpp_logger")
    subprocess.run(["g++", "-O1", "-o", exe, str(src)] + flags, check=True, capture_output=True)
    return exe


class MasterThread:
    """The launcher's own embedded master, on its own loop in a thread."""

    def __init__(self, port: int):
        from launcher.master.server import Master
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

        async def start() -> Any:
            master = Master("127.0.0.1", port, uri_host="127.0.0.1")
            await master.start()
            return master
        self.master = asyncio.run_coroutine_threadsafe(start(), self.loop).result(30)

    def stop(self) -> None:
        asyncio.run_coroutine_threadsafe(self.master.stop(), self.loop).result(30)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


@pytest.fixture(params=["rosmaster", "launcher-master"])
def graph(request, ros_env, tmp_path):
    """A master on a free loopback port (Debian's rosmaster, or ours), and the env for nodes."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
    env.update(PATH=ros_env["path"], ROS_MASTER_URI="http://127.0.0.1:%d/" % port,
               ROS_HOSTNAME="127.0.0.1", ROS_LOG_DIR=str(tmp_path / "ros_log"),
               ROS_HOME=str(tmp_path / "ros_home"), PYTHONUNBUFFERED="1")
    procs = Procs(env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    embedded = None
    if request.param == "rosmaster":
        procs.start(["rosmaster", "--core", "-p", str(port)])
    else:
        embedded = MasterThread(port)
    master = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])
    until(lambda: master_up(port), 20, what="rosmaster")
    py = tmp_path / "py_logger.py"
    py.write_text(PY_LOGGER)
    g = type("Graph", (), {})()
    g.env, g.procs, g.master, g.uri = env, procs, master, env["ROS_MASTER_URI"]
    g.py_logger, g.python, g.tmp = str(py), ros_env["python"], tmp_path
    try:
        yield g
    finally:
        procs.stop_all()
        if embedded is not None:
            embedded.stop()


@pytest.fixture
def rosout(graph):
    r = RosoutThread(graph.uri, str(graph.tmp / "run"))
    try:
        yield r
    finally:
        r.stop()


def log_lines(path: str) -> list[str]:
    try:
        with open(path, encoding="utf-8", errors="surrogateescape") as f:
            return f.read().splitlines()
    except FileNotFoundError:
        return []


def lines_of(path: str, node: str, text: str | None = None) -> list[str]:
    return [l for l in log_lines(path)
            if l.split(" ")[2:3] == [node] and (text is None or l.endswith("] " + text))]


def start_go(graph: Any, path: str, nodes: list[str]) -> None:
    """Once each node's "waiting" line reached rosout.log, let them all start logging."""
    for node in nodes:
        until(lambda: lines_of(path, node, "waiting"), 20, what="%s connected to rosout" % node)
    graph.master.setParam("/test", "/rosout_test/go", True)


LINE = re.compile(r"^(\d+\.\d{9}) (INFO|WARN|ERROR|FATAL) (\S+) \[([^:\]]+):(\d+)\(([^)]*)\)\] "
                  r"\[topics: ([^\]]*)\] (.*)$")


def check_four_levels(path: str, node: str, source: str, function: str) -> list[re.Match]:
    expected = [("INFO", "hello info 1"), ("WARN", "warn: two"), ("ERROR", "error three"),
                ("FATAL", "fatal four")]
    found = until(lambda: [LINE.match(l) for l in lines_of(path, node)
                           if not l.endswith("] waiting")][:5]
                  if len(lines_of(path, node)) and lines_of(path, node, "done") else None, 20,
                  what="the demo lines of %s" % node)
    assert [(m.group(2), m.group(8)) for m in found[:4]] == expected, found
    for m in found[:4]:
        assert m.group(3) == node
        assert m.group(4).endswith(source) and int(m.group(5)) > 0
        assert function in m.group(6)
        assert "/rosout" in m.group(7).split(", ")
    return found[:4]


def echo_rows(proc_out: str) -> list[list[str]]:
    return [row.split(",") for row in proc_out.splitlines()[1:] if row]


@pytest.mark.parametrize("kind", ["rospy", "roscpp"])
def test_node_logs_reach_rosout_log_and_rosout_agg(graph, rosout, cpp_logger, kind):
    path = rosout.rosout.log_path
    assert log_lines(path)[2].endswith("  Node Startup")
    echo_file = open(graph.tmp / "echo.csv", "w")
    graph.procs.start(["rostopic", "echo", "-p", "/rosout_agg"], stdout=echo_file)
    until(lambda: rosout.call(lambda: len(rosout.rosout._agg.links)), 20,
          what="rostopic echo subscribed to /rosout_agg")
    node = "/%s_logger" % kind
    if kind == "rospy":
        graph.procs.start([graph.python, graph.py_logger, "__name:=rospy_logger"])
        source, function = "py_logger.py", "main"
    else:
        graph.procs.start([cpp_logger, "__name:=roscpp_logger"])
        source, function = "cpp_logger.cpp", "main"
    start_go(graph, path, [node])
    matches = check_four_levels(path, node, source, function)

    # What a real `rostopic echo` received on /rosout_agg is what went into rosout.log.
    def agg_rows() -> list[list[str]]:
        rows = [r for r in echo_rows((graph.tmp / "echo.csv").read_text())
                if len(r) > 6 and r[5] == node and r[6] != "waiting"]
        return rows if len(rows) >= 5 else []
    rows = until(agg_rows, 20, what="/rosout_agg rows from rostopic echo")
    echo_file.close()
    # `rosnode info` sees both connections, described the way it describes roscpp's.
    info = graph.procs.output(["rosnode", "info", "/rosout"])
    assert re.search(r"\* topic: /rosout_agg\n    \* to: /rostopic_\S+\n    \* direction: outbound "
                     r"\(\d+ - 127\.0\.0\.1:\d+\) \[\d+\]\n    \* transport: TCPROS\n", info), info
    assert re.search(r"\* topic: /rosout\n    \* to: %s \(http://127\.0\.0\.1:\d+/\)\n    \* "
                     r"direction: inbound \(\d+ - 127\.0\.0\.1:\d+\) \[\d+\]\n" % node, info), info
    levels = {"2": "INFO", "4": "WARN", "8": "ERROR", "16": "FATAL"}
    for m, row in zip(matches, rows):
        stamp_ns = int(m.group(1).replace(".", ""))
        assert int(row[2]) == stamp_ns
        assert (levels[row[4]], row[6], row[7], row[9]) == (m.group(2), m.group(8), m.group(4),
                                                            m.group(5))


def test_rosnode_info_matches_the_reference_rosout(graph, rosout):
    ours = graph.procs.output(["rosnode", "info", "/rosout"])
    # The reference: Debian's roscpp rosout, alone on a second master.
    port = free_port()
    env = dict(graph.env, ROS_MASTER_URI="http://127.0.0.1:%d/" % port)
    ref_procs = Procs(env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        ref_procs.start(["rosmaster", "--core", "-p", str(port)])
        until(lambda: master_up(port), 20, what="second rosmaster")
        ref_procs.start(["/usr/lib/rosout/rosout"])
        until(lambda: "/rosout/set_logger_level" in subprocess.run(
            ["rosservice", "list"], env=env, capture_output=True, text=True).stdout, 20,
            what="reference rosout up")
        reference = ref_procs.output(["rosnode", "info", "/rosout"])
    finally:
        ref_procs.stop_all()

    def normalize(text: str) -> str:
        text = re.sub(r"http://[\d.]+:\d+/", "URI", text)
        return re.sub(r"Pid: \d+", "Pid: N", text)
    assert normalize(ours) == normalize(reference)
    assert "Pid: %d" % os.getpid() in ours


def test_logger_services_answer_rosservice(graph, rosout):
    out = graph.procs.output(["rosservice", "call", "/rosout/get_loggers"])
    assert 'name: "launcher.rosout"' in out
    graph.procs.output(["rosservice", "call", "/rosout/set_logger_level", "launcher.rosout", "error"])
    out = graph.procs.output(["rosservice", "call", "/rosout/get_loggers"])
    assert re.search(r'name: "launcher.rosout"\s+level: "error"', out)
    bad = subprocess.run(["rosservice", "call", "/rosout/set_logger_level", "nope", "debug"],
                         env=graph.env, capture_output=True, text=True, timeout=30)
    assert bad.returncode != 0 and "nope" in bad.stdout + bad.stderr
    import logging
    logging.getLogger("launcher.rosout").setLevel(logging.NOTSET)


def test_omit_topics_parameter_is_followed(graph, rosout):
    path = rosout.rosout.log_path
    graph.master.setParam("/test", "/rosout/omit_topics", True)
    until(lambda: rosout.call(lambda: rosout.rosout.omit_topics), 20, what="paramUpdate")
    graph.procs.start([graph.python, graph.py_logger, "__name:=rospy_logger"])
    start_go(graph, path, ["/rospy_logger"])
    line = until(lambda: lines_of(path, "/rospy_logger", "hello info 1"), 20, what="info line")[0]
    assert "[topics:" not in line and re.match(r"^\d+\.\d{9} INFO /rospy_logger \[", line)


class BadPublisher:
    """A node registered as a /rosout publisher that misbehaves on TCPROS (a test stand-in for a
    broken or hung node, which no real node can be made to be on demand)."""

    def __init__(self, master: Any, name: str, behaviour: str):
        from xmlrpc.server import SimpleXMLRPCServer
        self.behaviour = behaviour
        self.tcp = socket.socket()
        self.tcp.bind(("127.0.0.1", 0))
        self.tcp.listen(8)
        self.conns: list[socket.socket] = []
        self.rpc = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False, allow_none=True)
        self.rpc.register_function(
            lambda caller, topic, protos: [1, "", ["TCPROS", "127.0.0.1",
                                                   self.tcp.getsockname()[1]]], "requestTopic")
        for t in (threading.Thread(target=self.rpc.serve_forever, daemon=True),
                  threading.Thread(target=self._accept, daemon=True)):
            t.start()
        self.uri = "http://127.0.0.1:%d/" % self.rpc.server_address[1]
        master.registerPublisher(name, "/rosout", "rosgraph_msgs/Log", self.uri)

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.tcp.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.behaviour == "garbage":
                conn.sendall(b"\xff\xff\xff\x7f" + os.urandom(512))
            elif self.behaviour == "bad-frames":
                from launcher.net.tcpros import encode_header
                conn.sendall(encode_header({"callerid": "/bad", "md5sum": "*",
                                            "type": "rosgraph_msgs/Log"}))
                conn.sendall(b"\x10\x00\x00\x00" + os.urandom(16) + b"\xff\xff\xff\x7f")
            # "stall": accept and never say a word.

    def close(self) -> None:
        self.rpc.shutdown()
        self.rpc.server_close()
        self.tcp.close()
        for c in self.conns:
            c.close()


def test_bad_publishers_do_not_affect_a_good_one(graph, rosout, cpp_logger):
    path = rosout.rosout.log_path
    bad = [BadPublisher(graph.master, "/bad_%s" % b.replace("-", "_"), b)
           for b in ("garbage", "bad-frames", "stall")]
    # A registered publisher that is not there at all (a node that was killed -9).
    graph.master.registerPublisher("/dead", "/rosout", "rosgraph_msgs/Log",
                                   "http://127.0.0.1:%d/" % free_port())
    try:
        graph.procs.start([cpp_logger, "__name:=load_a", "500", "2000"])
        start_go(graph, path, ["/load_a"])
        until(lambda: lines_of(path, "/load_a", "done"), 20, what="all lines of /load_a")
        got = [l.rsplit("] ", 1)[1] for l in lines_of(path, "/load_a")]
        assert [g for g in got if g.startswith("load ")] == ["load %d" % i for i in range(500)]
        # The publishers that sent garbage were dropped; the good one is still connected.
        links = rosout.call(lambda: dict(rosout.rosout.node.subscriptions["/rosout"].links))
        assert bad[0].uri not in links and bad[1].uri not in links
        assert any(l.callerid_of_publisher == "/load_a" for l in links.values())
    finally:
        for b in bad:
            b.close()


def test_stop_mid_stream_keeps_everything_received(graph, cpp_logger):
    r = RosoutThread(graph.uri, str(graph.tmp / "run2"))
    stopped = False
    try:
        path = r.rosout.log_path
        for name in ("load_a", "load_b"):
            graph.procs.start([cpp_logger, "__name:=" + name, "4000", "2000"])
        start_go(graph, path, ["/load_a", "/load_b"])
        # Stop while both nodes are still sending, without waiting for the file to catch up.
        until(lambda: r.call(lambda: r.rosout.received) > 2000, 20, what="messages flowing")
        r.stop()
        stopped = True
        received = r.rosout.received
        lines = log_lines(path)
        # Every message rosout took in is in the file: the startup marker's 3 lines + one each.
        assert len(lines) == 3 + received and r.rosout.undecodable == 0
        for name in ("/load_a", "/load_b"):
            got = [l.rsplit("] ", 1)[1] for l in lines_of(path, name)]
            loads = [g for g in got if g.startswith("load ")]
            assert loads == ["load %d" % i for i in range(len(loads))]  # a prefix, no gaps
            assert 0 < len(loads) < 4000
    finally:
        if not stopped:
            r.stop()


def test_rosnode_kill_respawns_rosout(graph, rosout):
    before = graph.master.lookupNode("/test", "/rosout")[2]
    graph.procs.output(["rosnode", "kill", "/rosout"])
    after = until(lambda: (lambda u: u if u != before else None)(
        graph.master.lookupNode("/test", "/rosout")[2]), 20, what="a new /rosout registration")
    assert after.startswith("http://127.0.0.1:")
    graph.procs.start([graph.python, graph.py_logger, "__name:=rospy_logger"])
    start_go(graph, rosout.rosout.log_path, ["/rospy_logger"])
    until(lambda: lines_of(rosout.rosout.log_path, "/rospy_logger", "hello info 1"), 20,
          what="logging after the respawn")


def test_rosgraph_encodes_headers_like_us(graph):
    from launcher.net.tcpros import decode_header, encode_header
    fields = {"callerid": "/a", "topic": "/rosout", "md5sum": "*", "message_definition": "x=1\n"}
    script = ("import sys, rosgraph.network as n; sys.stdout.buffer.write("
              "n.encode_ros_handshake_header(%r))" % fields)
    theirs = subprocess.run([graph.python, "-c", script], capture_output=True, check=True,
                            env=graph.env).stdout
    # Field order carries no meaning (rosgraph sorts); lengths and layout must be identical.
    assert decode_header(theirs[4:]) == fields
    assert theirs == encode_header(dict(sorted(fields.items())))


def test_load_from_several_publishers_loses_nothing(graph, rosout, cpp_logger):
    """A short version of benchmarks/rosout_load.py: 3 roscpp nodes x 2000 msg/s for 1 s, plus a
    rospy node, all at once; every line reaches rosout.log, in each node's order."""
    path = rosout.rosout.log_path
    names = ["load_%d" % i for i in range(3)]
    for name in names:
        graph.procs.start([cpp_logger, "__name:=" + name, "2000", "2000"])
    graph.procs.start([graph.python, graph.py_logger, "__name:=py_load", "300"])
    nodes = ["/" + n for n in names] + ["/py_load"]
    start_go(graph, path, nodes)
    until(lambda: all(lines_of(path, n, "done") for n in nodes), timeout=60,
          what="every node's last line")
    for node, count in [(n, 2000) for n in nodes[:3]] + [("/py_load", 300)]:
        got = [l.rsplit("] ", 1)[1] for l in lines_of(path, node)]
        assert [g for g in got if g.startswith("load ")] == ["load %d" % i for i in range(count)]
    assert rosout.call(lambda: rosout.rosout.undecodable) == 0


def test_text_that_is_not_utf8_reaches_rosout_log_unchanged(graph, rosout, cpp_logger):
    path = rosout.rosout.log_path
    graph.procs.start([cpp_logger, "__name:=raw_bytes", "-1"])
    start_go(graph, path, ["/raw_bytes"])
    until(lambda: len([l for l in lines_of(path, "/raw_bytes") if "waiting" not in l]) >= 2, 20,
          what="the lines of /raw_bytes")
    with open(path, "rb") as f:
        raw = [l for l in f.read().split(b"\n") if b" /raw_bytes " in l and b"waiting" not in l]
    assert any(l.endswith(b" [topics: /t\xfe] raw \xff\xfe bytes") for l in raw), raw
    assert any(l.endswith(b"] done") for l in raw)
    assert rosout.call(lambda: rosout.rosout.undecodable) == 0
