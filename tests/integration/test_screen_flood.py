"""A screen flood through the launcher on a terminal (issue 36): two nodes at 20 MB/s together and a neighbour that
crashes and respawns; every line whole and in order on the terminal and in the copies, the relay's fast path taken
(its counter in the launch log), and a view attached in the middle gets the recent output and what follows."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time

import pytest

from helpers import free_port, until
from running import get_param, make_package, master_up, ros_env, stop_group, write_launch
from launcher.net.xmlrpc import call_blocking

pytestmark = pytest.mark.integration

LINE_BYTES = 100
# numbered lines of LINE_BYTES at RATE MB/s for SECONDS (0: until stopped), in writes that cut lines anywhere; it
# rests (the rate's pauses) only at a line's end: a line left without its end for 0.2 s is passed on as it is
# (output/screen.py's PARTIAL_S, for prompts), which a 1 ms pause stretched by a loaded machine could reach
FLOOD = """#!%s
import os, sys, time
name, rate, seconds = sys.argv[1], float(sys.argv[2]) * 1e6, float(sys.argv[3])
pad = b"abcdefghijklmnopqrstuvwxyz0123456789" * 4
def line(i):
    head = b"%%s %%08d ~" %% (name.encode(), i)
    return head + pad[i %% 36:i %% 36 + %d - 2 - len(head)] + b"~\\n"
total = int(rate * seconds) // %d if seconds else 1 << 62
write = (4093, 8191, 1500, 12001)
start, i, k, sent, pending, at = time.monotonic(), 0, 0, 0, b"", 0
while i < total or at < len(pending):
    if sent > (time.monotonic() - start) * rate:
        if at and pending[at - 1:at] != b"\\n":  # (it rests at a line's end: see FLOOD's comment)
            n = os.write(1, pending[at:pending.index(b"\\n", at) + 1])
            at, sent = at + n, sent + n
            continue
        time.sleep(0.001)
        continue
    if len(pending) - at < write[k %% 4] and i < total:
        due = min(total, i + 500)
        pending, at = pending[at:] + b"".join(line(j) for j in range(i, due)), 0
        i = due
    n = os.write(1, pending[at:at + write[k %% 4]])
    at, sent, k = at + n, sent + n, k + 1
""" % (sys.executable, LINE_BYTES, LINE_BYTES)

# a few whole lines, a line it never ends, then a crash; the launch's stop at the test's end ends it quietly (a
# KeyboardInterrupt's traceback would quote its source line, `os.write(1, b"crasher line ...`, on the terminal)
CRASHER = """#!%s
import os, signal, sys, time
signal.signal(signal.SIGINT, lambda *a: os._exit(0))
for i in range(20):
    os.write(1, b"crasher line %%d\\n" %% i)
    time.sleep(0.005)
os.write(1, b"crasher's last words without an end")
os.kill(os.getpid(), 9)
""" % sys.executable


NODE = "/flood1"  # (the view's name for it)
LAST_WORDS = b"crasher's last words without an end"


def expected(name: str, i: int) -> bytes:
    pad = b"abcdefghijklmnopqrstuvwxyz0123456789" * 4
    head = b"%s %08d ~" % (name.encode(), i)
    return head + pad[i % 36:i % 36 + LINE_BYTES - 2 - len(head)] + b"~"


def flood_lines(text: bytes, names: list[str]) -> dict[str, list[int]]:
    """Each node's line numbers in the order they came; a flood line that is not whole fails the test."""
    seen: dict[str, list[int]] = {n: [] for n in names}
    for line in text.replace(b"\r\n", b"\n").split(b"\n"):
        if b"~" not in line:
            continue
        line = line.replace(LAST_WORDS, b"")  # (the neighbour's line without an end: what comes next follows it)
        m = re.match(rb"(flood\d) (\d{8}) ~", line)
        assert m and line == expected(m.group(1).decode(), int(m.group(2))), "a broken line: %r" % line[:200]
        seen[m.group(1).decode()].append(int(m.group(2)))
    return seen


@pytest.fixture
def pkgs(tmp_path, ros_env):
    make_package(str(tmp_path / "pkgs"), "flood_tests", {"flood": FLOOD, "crasher": CRASHER})
    return str(tmp_path / "pkgs")


def on_a_terminal(tmp_path, env: dict, port: int, launch: str) -> tuple[subprocess.Popen, subprocess.Popen, int, str]:
    """The launch on a pty whose other side `cat` copies into a file as fast as it comes."""
    terminal, own = os.openpty()
    screen = str(tmp_path / "terminal")
    cat = subprocess.Popen(["cat"], stdin=terminal, stdout=open(screen, "wb"), stderr=subprocess.DEVNULL)
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "-p", str(port), launch], env=env, stdin=own,
                            stdout=own, stderr=own, start_new_session=True)
    os.close(own)
    return proc, cat, terminal, screen


def read(path: str) -> bytes:
    with open(path, "rb") as f:
        return f.read()


def launch_log(tmp_path) -> str:
    latest = tmp_path / "log" / "latest"
    return "".join(p.read_text() for p in latest.glob("roslaunch-*.log"))


def test_two_floods_and_a_crashing_neighbour_keep_every_line_whole_and_in_order(tmp_path, pkgs):
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    seconds = 3
    launch = write_launch(str(tmp_path), """
      <node pkg="flood_tests" type="flood" name="flood1" output="screen" args="flood1 10 %d"/>
      <node pkg="flood_tests" type="flood" name="flood2" output="screen" args="flood2 10 %d"/>
      <node pkg="flood_tests" type="crasher" name="crasher" output="screen" respawn="true" respawn_delay="0.1"/>
    """ % (seconds, seconds))
    per_node = 10 * 1000 * 1000 * seconds // LINE_BYTES
    proc, cat, terminal, screen = on_a_terminal(tmp_path, env, port, launch)
    try:
        until(lambda: len(re.findall(rb"\[flood\d-\d\] process has finished cleanly", read(screen))) == 2, 180, 0.2,
              what="both floods' ends on the terminal")
        until(lambda: len(re.findall(rb"process\[crasher-\d\]: started", read(screen))) >= 3, 60, 0.2,
              what="the neighbour's third start")
    finally:
        stop_group(proc, 30)
        cat.wait(30)
        os.close(terminal)
    # the copies first: they are what the relay read from each node, so a failure below is in what it wrote
    for name in ("flood1", "flood2"):
        copy, = (tmp_path / "log" / "latest").glob("%s-*-stdout.log" % name)
        assert flood_lines(copy.read_bytes(), [name])[name] == list(range(per_node))
    text = read(screen)
    for name in ("flood1", "flood2"):  # (which lines the terminal lacks, should it lack any)
        on_screen = set(int(n) for n in re.findall(rb"%s (\d{8}) ~" % name.encode(), text))
        missing = sorted(set(range(per_node)) - on_screen)
        assert not missing, "%s: %d lines missing on the terminal, from %d to %d" % (
            name, len(missing), missing[0], missing[-1])
    seen = flood_lines(text, ["flood1", "flood2"])
    for name, numbers in seen.items():
        assert numbers == list(range(per_node)), "%s: %d lines, not each once in order" % (name, len(numbers))
    # the neighbour's lines are whole too, and its line without an end is there (passed on at its exit)
    crasher = [line for line in text.replace(b"\r\n", b"\n").split(b"\n") if b"crasher line" in line]
    assert len(crasher) >= 40 and all(re.fullmatch(rb"crasher line \d+", line) for line in crasher), crasher
    assert text.count(LAST_WORDS) >= 2
    # and no byte of it was taken line by line: the fast path ran (the launch log's count)
    as_read, by_line = map(int, re.search(r"screen relay: (\d+) bytes .*, (\d+) line by line",
                                          launch_log(tmp_path)).groups())
    assert by_line == 0 and as_read >= 2 * per_node * LINE_BYTES


def test_every_line_reaches_the_terminal_of_an_unbuffered_launch_stopped_and_continued_in_a_flood(tmp_path, pkgs):
    # PYTHONUNBUFFERED=1 (the unit `launcher install` writes, many container images): the launch's stdout is the raw
    # descriptor. Stopped and continued (Ctrl-Z and fg, a profiler attaching) while its console thread waits in a
    # write to the full terminal, that write ends with part of it taken; the rest used to be lost on the terminal
    port = free_port()
    env = dict(ros_env(str(tmp_path), port, pkgs), PYTHONUNBUFFERED="1")
    seconds = 3
    launch = write_launch(str(tmp_path), '<node pkg="flood_tests" type="flood" name="flood1" output="screen" '
                                         'args="flood1 10 %d"/>' % seconds)
    per_node = 10 * 1000 * 1000 * seconds // LINE_BYTES
    proc, cat, terminal, screen = on_a_terminal(tmp_path, env, port, launch)
    stops = 0
    try:
        until(lambda: b"flood1 00000000 ~" in read(screen), 120, 0.05, what="the flood going")
        finished = re.compile(rb"\[flood1-\d\] process has finished")
        while not finished.search(read(screen)[-4096:]) and stops < 20000:
            for _ in range(50):
                os.kill(proc.pid, signal.SIGSTOP)
                time.sleep(0.0003)
                os.kill(proc.pid, signal.SIGCONT)
                time.sleep(0.0017)
            stops += 50
        assert finished.search(read(screen)), "the flood's end never reached the terminal"
    finally:
        os.kill(proc.pid, signal.SIGCONT)
        stop_group(proc, 30)
        cat.wait(30)
        os.close(terminal)
    assert stops >= 500
    copy, = (tmp_path / "log" / "latest").glob("flood1-*-stdout.log")
    assert flood_lines(copy.read_bytes(), ["flood1"])["flood1"] == list(range(per_node))
    on_screen = flood_lines(read(screen), ["flood1"])["flood1"]
    assert on_screen == list(range(per_node)), "%d of %d lines on the terminal, after %d stops" % (
        len(set(on_screen)), per_node, stops)


def test_a_view_attached_in_the_middle_gets_the_recent_output_and_what_follows(tmp_path, pkgs):
    port = free_port()
    env = ros_env(str(tmp_path), port, pkgs)
    launch = write_launch(str(tmp_path), '<node pkg="flood_tests" type="flood" name="flood1" output="screen" '
                                         'args="flood1 1 0"/>')
    proc, cat, terminal, screen = on_a_terminal(tmp_path, env, port, launch)
    try:
        until(lambda: len(re.findall(rb"flood1 \d{8} ~", read(screen))) > 20000, 120, 0.2, what="the flood going")
        uris = until(lambda: master_up(port) and (get_param(port, "/roslaunch") or {}).get("uris"), 60, 0.2,
                     what="the launch's server")
        (uri,) = uris.values()
        on_screen_before = len(re.findall(rb"flood1 \d{8} ~", read(screen)))
        # attached now: the last 16 KiB of the node's output (as `launcher ui` asks for them), then what comes
        code, _, answer = call_blocking(uri, "launcher_output", json.dumps({NODE: -16384}), 0)
        assert code == 1
        answer = json.loads(answer)
        shown = [answer["output"][NODE]]
        offsets = answer["offsets"]
        copy, = (tmp_path / "log" / "latest").glob("flood1-*-stdout.log")
        written_then = copy.stat().st_size // LINE_BYTES
        while len(shown) < 30:
            code, _, later = call_blocking(uri, "launcher_output", json.dumps(offsets), 5)
            later = json.loads(later)
            offsets.update(later["offsets"])
            if NODE in later["output"]:
                shown.append(later["output"][NODE])
    finally:
        stop_group(proc, 30)
        cat.wait(30)
        os.close(terminal)
    text = "".join(shown).encode()
    first_line_end = text.index(b"\n") + 1  # (the recent output begins in the middle of a line)
    last_line_end = text.rindex(b"\n") + 1  # (and the last answer may end in one)
    numbers = flood_lines(text[first_line_end:last_line_end], ["flood1"])["flood1"]
    assert len(numbers) > 16384 // LINE_BYTES * 3  # the recent lines and many more
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers)))  # none missing, none twice, in order
    # the first ones were recent: within the last 16 KiB written when the view attached
    assert on_screen_before - 16384 // LINE_BYTES - 1 <= numbers[0] <= written_then
