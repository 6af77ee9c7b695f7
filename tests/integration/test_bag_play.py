"""`launcher bag play` of bags Debian's rosbag recorded, to real roscpp and rospy subscribers; --clock for use_sim_time."""

from __future__ import annotations

import os
import pty
import re
import signal
import socket
import subprocess
import threading
import xmlrpc.client

import pytest
from rosbags.rosbag1 import Writer

from bagparts import graph_env, ROS_PYTHON, bag_argv, debian_read, listeners, our_env, talkers
from helpers import Procs, until
from running import RosMaster

from launcher.net.tcpros import FrameDecoder, encode_header

COUNT = 50

# A use_sim_time rospy node: for each message on /chatter, "<data> <rospy.get_time()>".
SimTimeListener = """#!%s
import sys, rospy
from std_msgs.msg import String
rospy.init_node("sim_listener")
def on(msg):
    sys.stdout.write("%%s %%.9f\\n" %% (msg.data, rospy.get_time()))
    sys.stdout.flush()
rospy.Subscriber("/chatter", String, on, queue_size=1000)
rospy.spin()
""" % ROS_PYTHON


@pytest.fixture
def graph(tmp_path, ros_env):
    master = RosMaster(str(tmp_path))
    env = graph_env(str(tmp_path), master.port)
    procs = Procs(env)
    yield env, procs
    procs.stop_all()
    master.stop()


def debian_recording(tmp_path, env, procs) -> str:
    """A bag Debian's rosbag record made of a roscpp talker's COUNT messages on /chatter."""
    bag = str(tmp_path / "debian.bag")
    rec = procs.start(["rosbag", "record", "-O", bag, "-l", str(COUNT), "/chatter"],
                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs.start(talkers(str(tmp_path))["roscpp"] + ["/chatter", "m", str(COUNT), "100", "1"])
    assert rec.wait(60) == 0
    until(lambda: os.path.exists(bag), 10, what="rosbag's bag closed")
    return bag


def lines(path: str) -> list[str]:
    with open(path) as f:
        return f.read().splitlines()


def test_debian_bag_played_to_roscpp_and_rospy_subscribers(tmp_path, graph):
    env, procs = graph
    bag = debian_recording(tmp_path, env, procs)
    want = ["m %d" % n for n in range(COUNT)]
    # one run per listener: --wait-for-subscribers (as rosbag's) waits for a first subscriber, not for all
    for kind, argv in listeners(str(tmp_path)).items():
        out = str(tmp_path / ("%s.out" % kind))
        procs.start(argv + ["/chatter_" + kind], stdout=open(out, "w"), stderr=subprocess.DEVNULL)
        player = subprocess.run(bag_argv("play", "-q", "--wait-for-subscribers", "-r", "5", bag,
                                         "/chatter:=/chatter_" + kind),
                                env=our_env(env), capture_output=True, text=True, timeout=60)
        assert player.returncode == 0, player.stderr
        until(lambda: len(lines(out)) >= COUNT, 30, what="%s listener's messages" % kind)
        assert lines(out) == want, kind


def test_remap_and_topics(tmp_path, graph):
    env, procs = graph
    bag = debian_recording(tmp_path, env, procs)
    out = str(tmp_path / "old.out")
    procs.start(listeners(str(tmp_path))["rospy"] + ["/chatter_old"], stdout=open(out, "w"))
    player = subprocess.run(bag_argv("play", "-q", "--wait-for-subscribers", "-i", "--topics", "/chatter",
                                     "--bags", bag, "/chatter:=/chatter_old"),
                            env=our_env(env), capture_output=True, text=True, timeout=60)
    assert player.returncode == 0, player.stderr
    until(lambda: len(lines(out)) >= COUNT, 30, what="the remapped topic's messages")
    assert lines(out) == ["m %d" % n for n in range(COUNT)]


def test_clock_drives_a_use_sim_time_node(tmp_path, graph):
    env, procs = graph
    bag = debian_recording(tmp_path, env, procs)
    read = debian_read(bag, env)
    assert len(read["messages"]) == COUNT
    subprocess.run(["rosparam", "set", "/use_sim_time", "true"], env=env, check=True, timeout=30)
    script = tmp_path / "sim_listener"
    script.write_text(SimTimeListener)
    script.chmod(0o755)
    out = str(tmp_path / "sim.out")
    procs.start([str(script)], stdout=open(out, "w"))
    # -l: the node's /clock link may come after the first messages (rospy's time is 0 until then)
    player = procs.start(bag_argv("play", "-q", "--clock", "-l", "-r", "4", bag), env=our_env(env),
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)

    def sim_times() -> list[float]:
        return [float(line.split()[2]) for line in lines(out) if float(line.split()[2]) > 0]
    until(lambda: len(sim_times()) >= COUNT, 60, what="the sim-time node's messages on the bag's clock")
    os.killpg(player.pid, signal.SIGINT)
    assert player.wait(30) == 0, player.stderr.read()
    start = float(subprocess.run(["rosbag", "info", "--yaml", "--key", "start", bag], env=env, capture_output=True,
                                 text=True, check=True).stdout)
    duration = float(subprocess.run(["rosbag", "info", "--yaml", "--key", "duration", bag], env=env,
                                    capture_output=True, text=True, check=True).stdout)
    # the node's clock is the bag's (not the wall clock): every message seen at a time within the bag's span
    times = sim_times()
    assert all(start - 0.001 <= t <= start + duration + 0.001 for t in times), (start, duration, times[:3])


def test_bad_bag_is_a_clear_error(tmp_path, graph):
    env, _ = graph
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all\n" * 10)
    for cmd in ("play", "info"):
        out = subprocess.run(bag_argv(cmd, str(junk)), env=our_env(env), capture_output=True, text=True,
                             timeout=30)
        assert out.returncode == 1 and str(junk) in out.stderr and "Traceback" not in out.stderr, out.stderr


def test_latched_topic_stays_latched_and_start_duration_select(tmp_path, graph):
    env, procs = graph
    bag = str(tmp_path / "latched.bag")
    rec = procs.start(bag_argv("record", "-O", bag, "-l", "1", "/latched"), env=our_env(env),
                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    pub = procs.start(["rostopic", "pub", "-l", "/latched", "std_msgs/String", "data: kept"],
                      stdout=subprocess.DEVNULL)
    assert rec.wait(60) == 0
    os.killpg(pub.pid, signal.SIGINT)  # from here on only our player has the message
    pub.wait(30)
    # the recording keeps the publisher's latching (Debian's rosbag reads the connection record)
    latching = subprocess.run([ROS_PYTHON, "-c", "import rosbag, sys; "
                               "print(rosbag.Bag(sys.argv[1])._connections[0].header['latching'].decode())", bag],
                              env=env, capture_output=True, text=True, timeout=30)
    assert latching.stdout.strip() == "1", latching
    player = procs.start(bag_argv("play", "-q", "-k", bag), env=our_env(env), stdout=subprocess.DEVNULL)
    out = str(tmp_path / "late.out")
    # subscribed after the message was played: only a latched topic gives it
    until(lambda: subprocess.run(["rostopic", "info", "/latched"], env=env, capture_output=True,
                                 text=True).stdout.count("* /play") >= 1, 30, what="our player publishing")
    procs.start(listeners(str(tmp_path))["rospy"] + ["/latched"], stdout=open(out, "w"))
    until(lambda: lines(out) == ["kept"], 30, what="the latched message")
    os.killpg(player.pid, signal.SIGINT)
    assert player.wait(30) == 0


def test_start_and_duration_play_a_slice(tmp_path, graph):
    env, procs = graph
    bag = debian_recording(tmp_path, env, procs)  # COUNT messages 10 ms apart
    out = str(tmp_path / "slice.out")
    procs.start(listeners(str(tmp_path))["roscpp"] + ["/chatter"], stdout=open(out, "w"))
    player = subprocess.run(bag_argv("play", "-q", "--wait-for-subscribers", "-s", "0.1", "-u", "0.2", bag),
                            env=our_env(env), capture_output=True, text=True, timeout=60)
    assert player.returncode == 0, player.stderr
    until(lambda: len(lines(out)) >= 10, 30, what="the slice")
    got = [int(line.split()[1]) for line in lines(out)]
    # about 20 of the 50, from about the 10th: contiguous, none of the bag's first or last ones
    assert got == list(range(got[0], got[0] + len(got))) and 5 <= got[0] <= 15 and 12 <= len(got) <= 28, got


def test_queue_keeps_the_newest_messages_for_a_stalled_subscriber(tmp_path, graph):
    # --queue 3 (roscpp's publisher queue): a subscriber that stops reading gets, once it reads again, what
    # its socket held and then the newest three; the oldest queued ones were dropped, never the newest
    env, procs = graph
    bag, count = str(tmp_path / "big.bag"), 200
    writer = Writer(bag)
    writer.open()
    conn = writer.add_connection("/big", "std_msgs/msg/String", msgdef="string data\n",
                                 md5sum="992ce8a1687cec8c8bd883ec73ca41d1", callerid="/talker")
    for n in range(count):
        data = ("m %d " % n).ljust(200_000, "x").encode()
        writer.write(conn, 10**18 + n * 10**6, len(data).to_bytes(4, "little") + data)
    writer.close()
    player = procs.start(bag_argv("play", "-i", "--queue", "3", "--wait-for-subscribers", "-k", bag,
                                  "__name:=player"), env=our_env(env), stdout=subprocess.PIPE, text=True)
    master = xmlrpc.client.ServerProxy(env["ROS_MASTER_URI"])
    uri = until(lambda: master.lookupNode("/test", "/player")[2] or None, 30, what="the player registered")
    until(lambda: "/big" in [t for t, _ in master.getPublishedTopics("/test", "")[2]], 30, what="/big advertised")
    _, _, (_, host, port) = xmlrpc.client.ServerProxy(uri).requestTopic("/test", "/big", [["TCPROS"]])
    sub = socket.socket()
    sub.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 65536)  # a small window: the player soon has to queue
    sub.connect((host, port))
    sub.sendall(encode_header({"callerid": "/stalled", "topic": "/big", "md5sum": "*",
                               "type": "std_msgs/String", "tcp_nodelay": "1"}))
    done = threading.Event()
    threading.Thread(target=lambda: [done.set() for line in player.stdout if "Done." in line], daemon=True).start()
    assert done.wait(60), "the player never finished"  # every message published while we did not read
    sub.settimeout(30)
    decoder, frames, last = FrameDecoder(), [], b"m %d " % (count - 1)
    while not frames or not frames[-1][4:].startswith(last):  # (a frame: the string's length, then it)
        frames += decoder.feed(sub.recv(1 << 20))
    sub.close()
    got = [int(f[4:16].split()[1]) for f in frames[1:]]  # (frames[0]: the player's header)
    assert got[-3:] == [count - 3, count - 2, count - 1], got
    assert len(got) < count // 2 and got == sorted(got), got


def short_bag(path: str, count: int = 20) -> str:
    writer = Writer(path)
    writer.open()
    conn = writer.add_connection("/chatter", "std_msgs/msg/String", msgdef="string data\n",
                                 md5sum="992ce8a1687cec8c8bd883ec73ca41d1", callerid="/talker")
    for n in range(count):
        data = b"m %d" % n
        writer.write(conn, 10**18 + n * 10**7, len(data).to_bytes(4, "little") + data)
    writer.close()
    return path


def said(out: str) -> str:
    """A player's stdout without what differs by design: the time in its log line, roscpp's colour codes, and the
    status lines (each written between two carriage returns)."""
    out = re.sub(r"\x1b\[0m", "", out)
    out = re.sub(r"^\[ INFO\] \[\d+\.\d+\]", "[ INFO] [T]", out, flags=re.M)
    return re.sub(r"\r[^\r]*\r", "", out)


def test_said_as_rosbag_play_says_it(tmp_path, graph):
    env, procs = graph
    bag = short_bag(str(tmp_path / "short.bag"))
    for args in ([], ["-q"], ["-d", "0.5"], ["-q", "-d", "0"]):
        # (bytes: text mode would make each carriage return a newline)
        theirs = subprocess.run(["/usr/lib/rosbag/play", *args, bag], env=env, capture_output=True, timeout=60)
        ours = subprocess.run(bag_argv("play", *args, bag), env=our_env(env), capture_output=True, timeout=60)
        assert theirs.returncode == ours.returncode == 0, (theirs.stderr, ours.stderr)
        assert said(ours.stdout.decode()) == said(theirs.stdout.decode()), args
        assert b"Bag Time" not in ours.stdout  # a pipe: no status line (rosbag writes it there too)


def test_status_line_on_a_terminal_only(tmp_path, graph):
    env, procs = graph
    bag = short_bag(str(tmp_path / "short.bag"))
    for args, status in (([], True), (["-q"], False)):
        leader, follower = pty.openpty()
        player = subprocess.Popen(bag_argv("play", *args, bag), env=our_env(env), stdin=subprocess.DEVNULL,
                                  stdout=follower, stderr=subprocess.DEVNULL, start_new_session=True)
        os.close(follower)
        out = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # EIO: the player closed its end
                break
            if not chunk:
                break
            out += chunk
        os.close(leader)
        assert player.wait(30) == 0
        line = re.search(rb"\r \[RUNNING\]  Bag Time: +(\d+\.\d{6})   Duration: (\d+\.\d{6}) / 0\.190000 +\r", out)
        assert bool(line) == status, out
        if status:
            assert float(line.group(1)) >= 1e9 and 0 <= float(line.group(2)) <= 0.19
        assert out.replace(b"\r\n", b"\n").endswith(b"\nDone.\n"), out


def test_hz_without_clock_is_said_to_do_nothing(tmp_path, graph):
    env, _ = graph
    bag = short_bag(str(tmp_path / "short.bag"), 2)
    out = subprocess.run(bag_argv("play", "-q", "-d", "0", "--hz", "50", bag), env=our_env(env), capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0 and "--hz 50 has no effect without --clock" in out.stderr, out.stderr
