"""TCPROS publishers that lie, met by `launcher bag record` and by the stall watch of a launch.

Fake publishers (tests/integration/nodes/lying_publisher.py: real sockets, registered on our master) beside a
real rospy talker. Each lie is one warning line naming the publisher and the topic, the connection is dropped
and tried again as it deserves (a refusal: only when the publisher advertises again; a broken link: after 1, 2,
4, 8 ... s), the talker's messages are all recorded (all counted by the watch), the process's memory stays
bounded, and no asyncio future is left with an exception nobody retrieved. A publisher faster than the disk
loses its oldest messages with rosbag's warning and is never disconnected.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from bagparts import RospyTalker, bag_argv, debian_read, graph_env, our_env
from helpers import ROS_PATH, ROS_PYTHON, Procs, free_port, until
from running import HERE, Launcher, make_package, master_up, write_launch
from running import ros_env as run_env

pytestmark = pytest.mark.integration

LIAR = os.path.join(HERE, "nodes", "lying_publisher.py")
LIES = ("error", "wrongtype", "huge", "slowheader", "garbage", "midframe")
BROKEN_FRAMES = ("huge", "garbage", "midframe")  # (tried at 0, 1, 3, 7 and 15 s)
# what a process may hold, whatever the liars claim (a 900 MB frame announced, 2 GB lengths): it starts near 30 MB
RSS_BOUND = 120 << 20
URI = r"http://127\.0\.0\.1:\d+/"
HANDSHAKE_S = 10.0  # (tcpros.HANDSHAKE_TIMEOUT_S: these are the words a user reads)


def accepts(log_dir: str, mode: str) -> list[float]:
    """When the liar accepted each TCPROS connection (its own clock)."""
    return [float(t) for what, t in events(log_dir, mode) if what == "accept"]


def events(log_dir: str, mode: str) -> list[tuple[str, str]]:
    try:
        with open(os.path.join(log_dir, mode + ".log")) as f:
            return [tuple(line.split()) for line in f if line.strip()]  # type: ignore[misc]
    except FileNotFoundError:
        return []


class RssPeak(threading.Thread):
    """The highest resident set size of a process, sampled every 0.1 s until it ends."""

    def __init__(self, pid: int):
        super().__init__(daemon=True)
        self.pid = pid
        self.peak = 0
        self.start()

    def run(self) -> None:
        while True:
            try:
                with open("/proc/%d/status" % self.pid) as f:
                    kb = next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
            except (OSError, StopIteration):
                return
            self.peak = max(self.peak, kb << 10)
            time.sleep(0.1)


def doubling(times: list[float], slack: float) -> bool:
    """The gaps between attempts are 1, 2, 4, 8 ... s (each may be late by up to `slack`)."""
    gaps = [b - a for a, b in zip(times, times[1:])]
    return all(d - 0.05 <= g <= d + slack for d, g in zip((1.0, 2.0, 4.0, 8.0, 16.0), gaps))


def no_internal_error(err: str) -> None:
    for bad in ("Traceback", "never retrieved", "exception was never", "Exception in callback"):
        assert bad not in err, err


# --------------------------------------------------------------------------- bag record

@pytest.fixture(scope="module")
def recording(ros_env, tmp_path_factory):
    """One `launcher bag record` of the six liars' topics and a rospy talker's, on `launch --core`, until the
    liars that are tried again have been tried four times and the slow one twice; the refusing one is made to
    advertise again on the way."""
    tmp = str(tmp_path_factory.mktemp("liars"))
    port = free_port()
    env = dict(graph_env(tmp, port), LIAR_LOG=tmp)
    procs = Procs(env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    core_err = open(os.path.join(tmp, "core.err"), "w")
    procs.start([sys.executable, "-m", "launcher", "--core", "-p", str(port)],
                env=dict(env, PATH=os.environ.get("PATH", "")), stderr=core_err)
    until(lambda: master_up(port), 30, what="launch --core up")
    liars = {mode: procs.start([sys.executable, LIAR, mode, "/evil_" + mode]) for mode in LIES}
    until(lambda: all(events(tmp, m) for m in LIES), 30, what="the liars registered")
    talker = os.path.join(tmp, "talker")
    with open(talker, "w") as f:
        f.write(RospyTalker)
    os.chmod(talker, 0o755)
    procs.start([talker, "/chatter", "py", "0", "50", "1"])  # from "py 0" on, once the recorder is connected
    bag = os.path.join(tmp, "liars.bag")
    out, err = os.path.join(tmp, "rec.out"), os.path.join(tmp, "rec.err")
    with open(out, "w") as o, open(err, "w") as e:
        rec = procs.start(bag_argv("record", "-O", bag, "/chatter", *("/evil_" + m for m in LIES)),
                          env=our_env(env), stdout=o, stderr=e)
    rss = RssPeak(rec.pid)
    try:
        until(lambda: accepts(tmp, "error"), 30, what="the recorder connecting")
        until(lambda: len(accepts(tmp, "huge")) >= 4 and len(accepts(tmp, "slowheader")) >= 2, 40, 0.1,
              what="the liars tried again")
        refused_before = len(accepts(tmp, "error"))
        liars["error"].send_signal(signal.SIGUSR1)  # it advertises again: the master sends a publisherUpdate
        until(lambda: len(accepts(tmp, "error")) >= 2, 20, what="the refusing liar tried again")
        until(lambda: all(len(accepts(tmp, m)) >= 5 for m in BROKEN_FRAMES), 20, 0.1, what="a fifth try of each")
        os.killpg(rec.pid, signal.SIGINT)
        rec.wait(30)
        rss.join(5)
        with open(err) as f:
            stderr = f.read()
        with open(out) as f:
            stdout = f.read()
        yield {"tmp": tmp, "rc": rec.returncode, "stderr": stderr, "stdout": stdout, "rss": rss.peak,
               "refused_before": refused_before, "bag": debian_read(bag, env)}
    finally:
        procs.stop_all()
        core_err.close()


def recorded_whole(rec: dict) -> None:
    """What every test of the recording checks too: a clean end, the talker's messages all in the bag, no internal
    error, every line of stderr a warning about one liar, memory bounded."""
    assert rec["rc"] == 0, rec["stderr"]
    data = [d for t, d in rec["bag"]["messages"] if t == "/chatter"]
    assert len(data) > 200 and data == ["py %d" % n for n in range(len(data))]
    no_internal_error(rec["stderr"])
    for line in rec["stderr"].splitlines():
        assert re.match(r"publisher %s( \(/liar_\w+\))? on /evil_\w+: " % URI, line), line
    assert rec["rss"] < RSS_BOUND, rec["rss"]


def warnings(rec: dict, mode: str) -> list[str]:
    return [line for line in rec["stderr"].splitlines() if " on /evil_%s: " % mode in line]


def test_an_error_header_is_dropped_until_the_publisher_advertises_again(recording):
    lines = warnings(recording, "error")
    assert len(lines) == 2 and all(re.fullmatch(r"publisher %s on /evil_error: refused the connection: go away; "
                                                r"dropping the connection until it advertises again" % URI, line)
                                   for line in lines), lines
    assert recording["refused_before"] == 1  # not tried again while the others were, four times
    assert len(accepts(recording["tmp"], "error")) == 2
    recorded_whole(recording)


def test_a_header_of_no_message_type_is_dropped_and_not_tried_again(recording):
    lines = warnings(recording, "wrongtype")
    assert len(lines) == 1 and re.fullmatch(
        r"publisher %s \(/liar_wrongtype\) on /evil_wrongtype: sent type 'no type here', md5sum 'nonsense': not a "
        r"message type and its md5sum; dropping the connection until it advertises again" % URI, lines[0]), lines
    assert len(accepts(recording["tmp"], "wrongtype")) == 1
    assert "/evil_wrongtype" not in recording["bag"]["topics"]
    recorded_whole(recording)


@pytest.mark.parametrize("mode, words", [
    ("huge", "frame of 2147483647 bytes exceeds the 1000000000 byte limit"),
    ("garbage", "frame of 1112686919 bytes exceeds the 1000000000 byte limit"),  # "GARB" read as a length
    ("midframe", "closed the connection in the middle of a frame (100000 of its 900000000 bytes)"),
])
def test_a_broken_frame_is_dropped_and_tried_again_after_doubling_delays(recording, mode, words):
    lines = warnings(recording, mode)
    delays = [re.fullmatch(r"publisher %s \(/liar_%s\) on /evil_%s: %s; dropping the connection, trying again in "
                           r"(\d+) s" % (URI, mode, mode, re.escape(words)), line) for line in lines]
    assert all(delays) and [m.group(1) for m in delays][:4] == ["1", "2", "4", "8"], lines
    tries = accepts(recording["tmp"], mode)
    assert len(tries) >= 5 and doubling(tries, 0.5), tries
    if mode == "midframe":  # the whole message before the cut frame is recorded, once per connection
        data = [d for t, d in recording["bag"]["messages"] if t == "/evil_midframe"]
        assert data == ["m %d" % n for n in range(len(tries))]
        assert "handshake" not in recording["stderr"]
    recorded_whole(recording)


def test_a_header_sent_one_byte_a_second_meets_the_handshake_deadline(recording):
    lines = warnings(recording, "slowheader")
    delays = [re.fullmatch(r"publisher %s on /evil_slowheader: sent no whole connection header in 10 s \(1[01] bytes "
                           r"came\); dropping the connection, trying again in (\d+) s" % URI, line) for line in lines]
    assert delays and all(delays) and [m.group(1) for m in delays][:2] == ["1", "2"][:len(delays)], lines
    tries = accepts(recording["tmp"], "slowheader")
    gone = [float(t) for what, t in events(recording["tmp"], "slowheader") if what == "eof"]
    # dropped at the deadline (the liar sees the close at its next byte, within a second), tried again 1 s later
    assert HANDSHAKE_S - 0.05 <= gone[0] - tries[0] <= HANDSHAKE_S + 1.5, (tries, gone)
    assert HANDSHAKE_S + 1.0 - 0.05 <= tries[1] - tries[0] <= HANDSHAKE_S + 2.0, tries
    recorded_whole(recording)


def test_a_publisher_faster_than_the_disk_loses_its_oldest_messages_and_stays_connected(ros_env, tmp_path):
    """-b 1 with bz2 (the writer compresses at a few MB/s, the liar sends 256 kB messages as fast as loopback
    takes them): rosbag's warning, the buffer's bound on memory, the publisher never disconnected, and the talker's
    messages all recorded (the topic holding the most of the buffer loses its oldest)."""
    tmp = str(tmp_path)
    port = free_port()
    env = dict(graph_env(tmp, port), LIAR_LOG=tmp)
    procs = Procs(env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        procs.start([sys.executable, "-m", "launcher", "--core", "-p", str(port)],
                    env=dict(env, PATH=os.environ.get("PATH", "")))
        until(lambda: master_up(port), 30, what="launch --core up")
        procs.start([sys.executable, LIAR, "fast", "/evil_fast"])
        until(lambda: events(tmp, "fast"), 30, what="the liar registered")
        talker = os.path.join(tmp, "talker")
        with open(talker, "w") as f:
            f.write(RospyTalker)
        os.chmod(talker, 0o755)
        procs.start([talker, "/chatter", "py", "0", "50", "1"])
        bag, err = os.path.join(tmp, "fast.bag"), os.path.join(tmp, "rec.err")
        with open(err, "w") as e:
            rec = procs.start(bag_argv("record", "-O", bag, "-b", "1", "-j", "/chatter", "/evil_fast"),
                              env=our_env(env), stdout=e, stderr=subprocess.STDOUT)
        rss = RssPeak(rec.pid)

        def said() -> str:
            with open(err) as f:
                return f.read()
        until(lambda: "buffer exceeded" in said(), 30, what="the buffer overflowing")
        time.sleep(3.0)  # (recording on, over the bound, for a while)
        os.killpg(rec.pid, signal.SIGINT)
        rec.wait(30)
        rss.join(5)
        out = said()
        assert rec.returncode == 0, out
        no_internal_error(out)
        assert re.search(r"\[ WARN\] \[[\d.]+\]: rosbag record buffer exceeded\.  Dropping oldest queued message\.",
                         out), out
        assert "dropping the connection" not in out, out
        # one connection, which the recorder never closed while it ran (the liar notes the close at its end)
        # (its "register" is noted once the master's answer is back: the watch's connection may come first)
        assert sorted(what for what, _ in events(tmp, "fast")) == ["accept", "eof", "register"]
        assert [what for what, _ in events(tmp, "fast") if what != "register"] == ["accept", "eof"]
        assert rss.peak < RSS_BOUND, rss.peak
        read = debian_read(bag, env)
        assert read["topics"]["/evil_fast"][1] >= 3, read["topics"]
        # the flooding topic loses its own oldest messages: the talker's are all there
        data = [d for t, d in read["messages"] if t == "/chatter"]
        assert len(data) > 50 and data == ["py %d" % n for n in range(len(data))], read["topics"]
    finally:
        procs.stop_all()


# --------------------------------------------------------------------------- the stall watch

LAUNCH = """
  <node pkg="liars" type="talker" name="talker" watch_topic="/chatter" watch_timeout="2"/>
  %s
  <node pkg="liars" type="liar" name="liar_fast" args="fast /evil_fast" watch_topic="/evil_fast" watch_timeout="2"/>
""" % "\n  ".join('<node pkg="liars" type="liar" name="liar_%s" args="%s /evil_%s" watch_topic="/evil_%s" '
                  'watch_timeout="3" on_stall="warn"/>' % (m, m, m, m) for m in LIES)

TALKER = """#!%s
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("/chatter", String, queue_size=10)
rate = rospy.Rate(20)
while not rospy.is_shutdown():
    pub.publish(String("hello"))
    rate.sleep()
""" % ROS_PYTHON


@pytest.fixture(scope="module")
def watching(ros_env, tmp_path_factory):
    """A launch whose every node is watched: the liars (on_stall="warn": they stay, so their tries can be
    counted), the fast liar and a rospy talker; until the liars tried again have been tried four times."""
    tmp = str(tmp_path_factory.mktemp("watch"))
    port = free_port()
    with open(LIAR) as f:
        liar = "#!%s\n%s" % (ROS_PYTHON, f.read())
    make_package(os.path.join(tmp, "ws"), "liars", {"liar": liar, "talker": TALKER})
    env = run_env(tmp, port, os.path.join(tmp, "ws"))
    env.update(PATH=ROS_PATH + ":" + env.get("PATH", ""), LIAR_LOG=tmp)
    lp = Launcher([write_launch(tmp, LAUNCH)], env, tmp)
    try:
        rss = RssPeak(lp.pid)
        until(lambda: all(len(accepts(tmp, m)) >= 5 for m in BROKEN_FRAMES) and len(accepts(tmp, "slowheader")) >= 2,
              60, 0.1, what="the liars tried again")
        yield {"tmp": tmp, "lp": lp, "rss": rss, "err": lp.stderr, "out": lp.stdout}
    finally:
        lp.close()


def watch_warnings(w: dict, mode: str) -> list[str]:
    return [line for line in w["err"].splitlines() if line.startswith("publisher ") and " on /evil_%s: " % mode in line]


def stalled(w: dict, mode: str) -> None:
    """The liar was found stalled: no message came (it is watched with on_stall="warn": it stays)."""
    assert re.search(r"\[liar_%s-\d+\] is stalled \(no message on /evil_%s " % (mode, mode), w["err"] + w["out"])


def watched_whole(w: dict) -> None:
    """What every watch test checks too: the talker and the fast liar never stalled, no internal error, the
    launcher still up with its memory bounded, and each of its warnings about a liar one line."""
    assert w["lp"].proc.poll() is None
    no_internal_error(w["err"])
    assert not re.search(r"\[(talker|liar_fast)-\d+\] is stalled", w["err"] + w["out"])
    for line in w["err"].splitlines():
        if line.startswith("publisher "):
            assert re.match(r"publisher %s( \(/liar_\w+\))? on /evil_\w+: " % URI, line), line
    assert w["rss"].peak < RSS_BOUND, w["rss"].peak
    # the fast liar: one connection, kept (its "register" is noted once the master's answer is back: the watch's
    # connection may come before it)
    assert sorted(what for what, _ in events(w["tmp"], "fast")) == ["accept", "register"]


@pytest.mark.parametrize("mode, words", [
    ("error", "refused the connection: go away"),
    ("wrongtype", "sent type 'no type here', md5sum 'nonsense': not a message type and its md5sum"),
])
def test_a_watch_refused_is_not_tried_again_in_that_run_and_the_node_is_stalled(watching, mode, words):
    lines = watch_warnings(watching, mode)
    assert len(lines) == 1 and re.fullmatch(r"publisher %s( \(/liar_%s\))? on /evil_%s: %s; dropping the connection, "
                                            r"not watched again until the node starts again"
                                            % (URI, mode, mode, re.escape(words)), lines[0]), lines
    assert len(accepts(watching["tmp"], mode)) == 1
    stalled(watching, mode)
    watched_whole(watching)


@pytest.mark.parametrize("mode, words", [
    ("huge", "frame of 2147483647 bytes exceeds the 1000000000 byte limit"),
    ("garbage", "frame of 1112686919 bytes exceeds the 1000000000 byte limit"),
    ("midframe", "closed the connection in the middle of a frame (100000 of its 900000000 bytes)"),
    ("slowheader", "sent no whole connection header in 10 s"),
])
def test_a_watch_broken_is_tried_again_after_doubling_delays(watching, mode, words):
    lines = watch_warnings(watching, mode)
    delays = [re.fullmatch(r"publisher %s( \(/liar_%s\))? on /evil_%s: %s; dropping the connection, trying again "
                           r"in (\d+) s" % (URI, mode, mode, re.escape(words) + (r" \(1[01] bytes came\)" if mode ==
                                                                                 "slowheader" else "")), line)
              for line in lines]
    assert delays and all(delays), lines
    want = ["1"] if mode == "slowheader" else ["1", "2", "4", "8"]  # (the slow one: its second try ends at 21 s)
    assert [m.group(2) for m in delays][:len(want)] == want, lines
    tries = accepts(watching["tmp"], mode)
    if mode != "slowheader":  # (its tries are 10 s apart and more: the deadline, then the delay)
        assert len(tries) >= 5 and doubling(tries, 0.5), tries
    stalled(watching, mode)
    watched_whole(watching)
