"""`launcher bag record` against Debian's rosbag: real rospy and roscpp publishers, Debian's rosbag reads what we wrote."""

from __future__ import annotations

import glob
import os
import signal
import subprocess
import threading

import pytest

from bagparts import MOUNT_NS, bag_argv, debian_env, debian_read, graph_env, listeners, mount_ns_missing, our_env, talkers
from helpers import ROOT, Procs, until
from running import RosMaster

from launcher.bag import buffer, record
from launcher.bag import main as bag_main

COUNT = 40


@pytest.fixture
def graph(tmp_path, ros_env):
    master = RosMaster(str(tmp_path))
    env = graph_env(str(tmp_path), master.port)
    procs = Procs(env)
    yield env, procs, talkers(str(tmp_path))
    procs.stop_all()
    master.stop()


def test_recorded_bag_is_what_debian_rosbag_reads(tmp_path, graph):
    env, procs, talk = graph
    bag = str(tmp_path / "run.bag")
    # -l: the recorder ends by itself once it has COUNT messages of each topic (no timing in the test)
    rec = procs.start(bag_argv("record", "-O", bag, "-l", str(COUNT), "/py_chatter", "/cpp_chatter"),
                      env=our_env(env), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs.start(talk["rospy"] + ["/py_chatter", "py", str(COUNT), "200", "1"])
    procs.start(talk["roscpp"] + ["/cpp_chatter", "cpp", str(COUNT), "200", "1"])
    out, _ = rec.communicate(timeout=60)
    assert rec.returncode == 0, out
    assert not os.path.exists(bag + ".active")
    info = subprocess.run(["rosbag", "info", bag], env=env, capture_output=True, text=True, timeout=60)
    assert info.returncode == 0, info.stderr
    assert "/py_chatter    %d msgs" % COUNT in info.stdout and "/cpp_chatter   %d msgs" % COUNT in info.stdout, info.stdout
    assert "std_msgs/String [992ce8a1687cec8c8bd883ec73ca41d1]" in info.stdout
    read = debian_read(bag, env)
    assert read["topics"] == {"/py_chatter": ["std_msgs/String", COUNT], "/cpp_chatter": ["std_msgs/String", COUNT]}
    for topic, prefix in (("/py_chatter", "py"), ("/cpp_chatter", "cpp")):
        assert [d for t, d in read["messages"] if t == topic] == ["%s %d" % (prefix, n) for n in range(COUNT)]


def test_sigint_mid_recording_leaves_an_indexed_bag(tmp_path, graph):
    env, procs, talk = graph
    bag = str(tmp_path / "cut.bag")
    # --chunksize 1: chunks reach the disk as the messages come, so the test can see the recording grow
    rec = procs.start(bag_argv("record", "-O", bag, "--chunksize", "1", "/chatter"), env=our_env(env),
                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs.start(talk["roscpp"] + ["/chatter", "m", "0", "100", "1"])
    until(lambda: os.path.getsize(bag + ".active") > 16384, 60, what="the recording growing",
          errors=(OSError,))
    assert not os.path.exists(bag)  # rosbag's name while writing
    os.killpg(rec.pid, signal.SIGINT)
    out, _ = rec.communicate(timeout=30)
    assert rec.returncode == 0, out
    assert os.path.exists(bag) and not os.path.exists(bag + ".active")
    read = debian_read(bag, env)
    data = [d for _, d in read["messages"]]
    first = int(data[0].split()[1])
    assert len(data) > 50 and data == ["m %d" % n for n in range(first, first + len(data))]
    assert read["topics"]["/chatter"] == ["std_msgs/String", len(data)]


def test_split_by_duration_and_max_splits(tmp_path, graph):
    env, procs, talk = graph
    prefix = str(tmp_path / "part")
    rec = procs.start(bag_argv("record", "-O", prefix, "--split", "--duration", "1", "--max-splits", "2", "-a",
                               "-x", "/rosout.*"),
                      env=our_env(env), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs.start(talk["rospy"] + ["/chatter", "m", "0", "50", "1"])
    until(lambda: os.path.exists(prefix + "_3.bag.active"), 60, what="a fourth split")
    os.killpg(rec.pid, signal.SIGINT)
    out, _ = rec.communicate(timeout=30)
    assert rec.returncode == 0, out
    bags = sorted(glob.glob(prefix + "_*"))
    # --max-splits 2: as rosbag, at most two files, the one being written included
    assert [os.path.basename(b) for b in bags] == ["part_2.bag", "part_3.bag"], bags
    data: list[str] = []
    for b in bags:
        read = debian_read(b, env)
        assert set(read["topics"]) == {"/chatter"}, read["topics"]
        data += [d for _, d in read["messages"]]
    first = int(data[0].split()[1])
    assert data == ["m %d" % n for n in range(first, first + len(data))]


def test_bad_options_are_usage_errors(tmp_path, graph):
    env, procs, _ = graph
    for args in (["-e", "(unclosed", "-O", "x"], ["--no-such-option", "/a"], ["-x", "[", "-a"], []):
        out = subprocess.run(bag_argv("record", *args), env=our_env(env), capture_output=True, text=True,
                             timeout=30, cwd=str(tmp_path))
        assert out.returncode == 2, (args, out.stderr)
        assert "Traceback" not in out.stderr and "usage:" in out.stderr, out.stderr


def test_rosnode_kill_closes_the_recording(tmp_path, graph):
    env, procs, talk = graph
    bag = str(tmp_path / "killed.bag")
    rec = procs.start(bag_argv("record", "-O", bag, "--chunksize", "1", "/chatter", "__name:=rec"), env=our_env(env),
                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs.start(talk["rospy"] + ["/chatter", "m", "0", "100", "1"])
    until(lambda: os.path.getsize(bag + ".active") > 8192, 60, what="the recording growing", errors=(OSError,))
    subprocess.run(["rosnode", "kill", "/rec"], env=env, check=True, capture_output=True, timeout=30)
    out, _ = rec.communicate(timeout=30)
    assert rec.returncode == 0, out
    read = debian_read(bag, env)
    assert read["topics"]["/chatter"][1] == len(read["messages"]) > 10


def test_killed_recording_is_recovered_by_reindex(tmp_path, graph):
    env, procs, talk = graph
    bag = str(tmp_path / "crash.bag")
    rec = procs.start(bag_argv("record", "-O", bag, "--chunksize", "1", "--lz4", "/chatter"), env=our_env(env),
                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs.start(talk["roscpp"] + ["/chatter", "m", "0", "200", "1"])
    until(lambda: os.path.getsize(bag + ".active") > 20000, 60, what="the recording growing", errors=(OSError,))
    os.killpg(rec.pid, signal.SIGKILL)  # no index written: the bag stays .active
    rec.wait(10)
    with open(bag + ".active", "r+b") as f:  # and its last record cut short
        f.truncate(os.path.getsize(bag + ".active") - 7)
    info = subprocess.run(bag_argv("info", bag + ".active"), env=our_env(env), capture_output=True, text=True,
                          timeout=30)
    assert info.returncode == 1 and "Traceback" not in info.stderr, info.stderr
    assert bag + ".active" in info.stderr and "launcher bag reindex" in info.stderr, info.stderr
    fixed = subprocess.run(bag_argv("reindex", bag + ".active"), env=our_env(env), capture_output=True, text=True,
                           timeout=60)
    assert fixed.returncode == 0, fixed.stderr
    read = debian_read(bag, env)
    data = [d for _, d in read["messages"]]
    assert len(data) > 20 and data == ["m %d" % n for n in range(len(data))]


def test_full_disk_ends_the_recording_with_a_readable_bag(tmp_path, graph, ros_part_missing):
    env, procs, talk = graph
    if mount_ns_missing():
        ros_part_missing(mount_ns_missing())
    disk, kept = tmp_path / "disk", tmp_path / "kept"
    disk.mkdir()
    kept.mkdir()
    # a 600 kB disk of its own: the recording fills it; what was on it is copied out before the namespace ends
    script = ('mount -t tmpfs -o size=600k none "$1" && shift && "$@"; echo $? > "%s/status"; cp "%s"/* "%s"/'
              % (kept, disk, kept))
    rec = procs.start(MOUNT_NS + ["sh", "-c", script, "sh", str(disk)]
                      + bag_argv("record", "-O", str(disk / "full.bag"), "--chunksize", "64", "/chatter"),
                      env=our_env(env), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs.start(talk["roscpp"] + ["/chatter", "m", "0", "500", "1", "1000"])
    out, _ = rec.communicate(timeout=60)
    assert (kept / "status").read_text().strip() == "1", out
    assert "No space left on device" in out and "Traceback" not in out, out
    assert not (kept / "full.bag.active").exists() and (kept / "full.bag").exists(), out
    read = debian_read(str(kept / "full.bag"), env)
    data = [d.split("x")[0] for _, d in read["messages"]]
    assert len(data) > 100 and data == ["m %d" % n for n in range(len(data))]


def test_node_records_what_a_node_subscribes_to(tmp_path, graph):
    env, procs, talk = graph
    bag = str(tmp_path / "node.bag")
    procs.start(listeners(str(tmp_path))["rospy"] + ["/wanted", "__name:=watched"], stdout=subprocess.DEVNULL)
    rec = procs.start(bag_argv("record", "-O", bag, "-l", "20", "--node", "/watched"), env=our_env(env),
                      stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    procs.start(talk["roscpp"] + ["/unwanted", "u", "0", "100", "1"])
    procs.start(talk["rospy"] + ["/wanted", "w", "0", "100", "2"])  # the watched node and the recorder
    out, _ = rec.communicate(timeout=60)
    assert rec.returncode == 0, out
    read = debian_read(bag, env)
    assert set(read["topics"]) == {"/wanted"}, read["topics"]
    assert [d for _, d in read["messages"]] == ["w %d" % n for n in range(20)]


def test_full_buffer_drops_the_oldest_messages(tmp_path, graph, monkeypatch, capsys):
    # -b 1: while the disk is stalled (the bag's writes held until everything was received), the buffer keeps
    # the newest megabyte and drops the oldest, with rosbag's warning; the writer then writes what it kept.
    # In this process (the disk is a patched BagFile.write); master, talker and sockets are real.
    env, procs, talk = graph
    bag = str(tmp_path / "buffered.bag")
    count, pad = 40, 100_000
    gate = threading.Event()
    write, close = record.BagFile.write, buffer.Buffer.close

    def stalled_write(self, *args):
        assert gate.wait(60), "the buffer was never closed"
        return write(self, *args)

    def open_gate(self):  # the recorder has all it will receive: let the disk go
        gate.set()
        close(self)

    monkeypatch.setattr(record.BagFile, "write", stalled_write)
    monkeypatch.setattr(buffer.Buffer, "close", open_gate)
    procs.start(talk["roscpp"] + ["/chatter", "m", str(count), "100", "1", str(pad)])
    argv = ["record", "-O", bag, "-b", "1", "-l", str(count), "/chatter", "__master:=" + env["ROS_MASTER_URI"],
            "__ip:=127.0.0.1"]
    assert bag_main.main(argv) == 0
    out = capsys.readouterr().out
    assert "rosbag record buffer exceeded.  Dropping oldest queued message." in out, out
    read = debian_read(bag, env)
    data = [d.rstrip("x") for _, d in read["messages"]]
    # the first messages (taken by the writer before the stall: the first, or the first few if more came before
    # the writer woke), then the newest ten that fit in 1 MB
    kept = (1 << 20) // (pad + 4)  # (a payload: its length, then the string)
    first = len(data) - kept
    assert 1 <= first <= 3 and data == ["m %d" % n for n in range(first)] + ["m %d" % n for n in range(count - kept,
                                                                                                       count)], data


def test_chunk_sized_messages_are_what_debian_rosbag_reads(tmp_path, ros_env, monkeypatch):
    # (each written as a chunk of its own, straight to the disk: Debian's reader and rosbag check agree)
    monkeypatch.syspath_prepend(os.path.join(ROOT, "tests", "bag"))
    from test_bagfile import mixed_bag

    bag = str(tmp_path / "mixed.bag")
    written = mixed_bag(bag)
    env = debian_env(dict(os.environ))
    read = debian_read(bag, env)
    assert read["topics"] == {"/big": ["std_msgs/String", 26], "/small": ["std_msgs/String", 14]}
    assert [(t, d) for t, d in read["messages"]] == [(t, p[4:].decode()) for t, _, p in written]
    check = subprocess.run(["rosbag", "check", bag], env=env, capture_output=True, text=True, timeout=60)
    assert check.returncode == 0 and "Bag file does not need any migrations" in check.stdout, check
