"""`launcher bag info` (text, -y, -k KEY, --freq) against Debian's `rosbag info` on the same bags, line by line:
bags written by Debian's rosbag (lz4, bz2 and mixed chunks, an hour long, one message, none) and one written by
rosbags as our recorder writes them (two connections on a topic)."""

from __future__ import annotations

import contextlib
import io
import json
import os
import subprocess

import pytest
from rosbags.rosbag1 import Writer

from bagparts import debian_env
from helpers import ROS_PYTHON

from launcher.bag import main as bag_main

# Debian's rosbag writing the bags: NAME -> how (each a function of the open Bag).
_MAKE = r"""
import sys, rosbag, rospy
from std_msgs.msg import String, Int32
out = sys.argv[1]
T0 = 1700000000.25

def t(s):
    return rospy.Time.from_sec(T0 + s)

def header(topic, mtype, caller):
    return {"topic": topic, "type": mtype._type, "md5sum": mtype._md5sum, "message_definition": mtype._full_text,
            "callerid": caller, "latching": "0"}

def plain(bag):
    # /chatter from two publishers (Debian's writer keeps one connection per topic: the rosbags bag below has
    # two), /count at an irregular pace
    for n in range(40):
        bag.write("/chatter", String("m %d" % n), t(n * 0.1), connection_header=header("/chatter", String,
                  "/talker_%d" % (n % 2)))
    for n, s in enumerate([0.0, 0.3, 0.5, 0.9, 1.0, 1.7, 2.0]):
        bag.write("/count", Int32(n), t(s))
    bag.write("/a/much/longer/topic/name", String("x" * 1000), t(3.0))

def compressed(kind):
    def make(bag):
        bag.compression = kind
        bag.chunk_threshold = 512
        for n in range(300):
            bag.write("/chatter", String("hello %d" % (n % 7) * 10), t(n * 0.01))
    return make

def mixed(bag):
    bag.chunk_threshold = 512
    for n in range(200):
        if n == 120:
            bag.compression = "lz4"
        bag.write("/chatter", String("hello %d" % n * 10), t(n * 0.5))

def long(bag):
    for n in range(6):
        bag.write("/slow", Int32(n), t(n * 1500.0))   # 2 hr 5 min

def minutes(bag):
    for n in range(3):
        bag.write("/slow", Int32(n), t(n * 61.5))

def single(bag):
    bag.write("/once", String("only"), t(0))

def empty(bag):
    pass

for name, make in [("plain", plain), ("lz4", compressed("lz4")), ("bz2", compressed("bz2")), ("mixed", mixed),
                   ("long", long), ("minutes", minutes), ("single", single), ("empty", empty)]:
    with rosbag.Bag("%s/%s.bag" % (out, name), "w") as bag:
        make(bag)
"""

# Debian's rosbag info on each argv, in one process: [[stdout, stderr, exit status], ...].
_INFO = r"""
import contextlib, io, json, sys
from rosbag.rosbag_main import info_cmd
results = []
for argv in json.loads(sys.argv[1]):
    out, err, code = io.StringIO(), io.StringIO(), 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            info_cmd(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
    results.append([out.getvalue(), err.getvalue(), code])
print(json.dumps(results))
"""

BAGS = ["plain", "lz4", "bz2", "mixed", "long", "minutes", "single", "empty", "rosbags"]
FORMS = [[], ["--freq"], ["-y"], ["-y", "--freq"]]
KEYS = ["duration", "start", "end", "size", "messages", "version", "indexed", "compression", "uncompressed",
        "types", "types[0]", "types[0].md5", "topics", "topics[1]", "topics[0].type", "topics[-1].messages",
        "topics[0].frequency", "path[0]", "nothing", "topics[9]"]


def string(text: str) -> bytes:
    data = text.encode()
    return len(data).to_bytes(4, "little") + data


def rosbags_bag(path: str) -> None:
    """A bag as our recorder writes it (rosbags' writer, connection records from the publishers' headers)."""
    writer = Writer(path)
    writer.open()
    conns = [writer.add_connection("/chatter", "std_msgs/msg/String", msgdef="string data\n",
                                   md5sum="992ce8a1687cec8c8bd883ec73ca41d1", callerid=caller, latching=1)
             for caller in ("/a", "/b")]
    for n in range(50):
        writer.write(conns[n % 3 == 0], 1_700_000_000_000_000_000 + n * 33_333_333, string("m %d" % n))
    writer.close()


@pytest.fixture(scope="module")
def bags(tmp_path_factory, ros_env):
    folder = tmp_path_factory.mktemp("bags")
    env = debian_env(dict(os.environ, TZ="UTC"))
    made = subprocess.run([ROS_PYTHON, "-c", _MAKE, str(folder)], env=env, capture_output=True, text=True,
                          timeout=120)
    assert made.returncode == 0, made.stderr
    rosbags_bag(str(folder / "rosbags.bag"))
    return folder, env


def debian_info(argvs: list[list[str]], env: dict[str, str], cwd: str) -> list[list]:
    out = subprocess.run([ROS_PYTHON, "-c", _INFO, json.dumps(argvs)], env=env, cwd=cwd, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def our_info(argv: list[str], cwd: str, monkeypatch) -> list:
    monkeypatch.chdir(cwd)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = bag_main.main(["info", *argv])
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code
    return [out.getvalue(), err.getvalue(), code]


def fields(text: str) -> list[tuple[str, str]]:
    """Each line as (field, rest): the field named when a line differs."""
    rows, field = [], ""
    for line in text.splitlines():
        name, sep, rest = line.partition(":")
        if sep and name.strip() and not name.startswith(" "):
            field = name
        rows.append((field, line))
    return rows


def test_info_forms_match_debian_rosbag(bags, monkeypatch):
    folder, env = bags
    monkeypatch.setenv("TZ", "UTC")  # the start and end lines are local times, as rosbag's
    argvs = [form + ["%s.bag" % name] for name in BAGS for form in FORMS]
    argvs.append(["-y", "plain.bag", "lz4.bag", "empty.bag"])  # several bags: '---' between them
    argvs.append(["plain.bag", "single.bag"])
    for argv, theirs in zip(argvs, debian_info(argvs, env, str(folder))):
        ours = our_info(argv, str(folder), monkeypatch)
        assert theirs[2] == 0 and not theirs[1], (argv, theirs)
        assert ours[2] == 0 and not ours[1], (argv, ours)
        for (field, mine), (_, debian) in zip(fields(ours[0]), fields(theirs[0])):
            assert mine == debian, "rosbag info %s, field %r:\n ours:   %r\n rosbag: %r" % (" ".join(argv), field,
                                                                                         mine, debian)
        assert ours[0] == theirs[0], argv  # the same number of lines, the same blank lines


def test_info_keys_match_debian_rosbag(bags, monkeypatch):
    folder, env = bags
    argvs = [["-y", "--freq", "-k", key, "%s.bag" % name] for name in ("plain", "lz4", "rosbags") for key in KEYS]
    for argv, theirs in zip(argvs, debian_info(argvs, env, str(folder))):
        ours = our_info(argv, str(folder), monkeypatch)
        assert ours[0] == theirs[0], argv
        assert ours[1] == theirs[1], argv  # an unknown key: rosbag's words
        # deliberately not as rosbag: an unknown key exits 1 (rosbag says so and exits 0)
        assert ours[2] == (1 if theirs[1] else 0), argv


def test_info_usage_errors(bags, monkeypatch):
    folder, _ = bags
    out = our_info(["-k", "duration", "plain.bag"], str(folder), monkeypatch)
    assert out[2] == 2 and "only specify key when printing in YAML" in out[1]
