"""Ready by output: the lines of a node's output file matched against the patterns nodes wait for."""

from __future__ import annotations

import os

from launcher.health import outputwatch
from launcher.health.outputwatch import LineMatcher, OutputFollower


def test_a_pattern_matches_a_whole_line_once_it_is_complete():
    m = LineMatcher()
    m.want("ready to go")
    m.want(r"port \d+$")
    m.feed(b"starting\nready ")
    assert m.matched == set()  # (half a line is no line yet)
    m.feed(b"to go!\r\nlistening on port 80")
    assert m.matched == {"ready to go"}
    m.feed(b"\n")
    assert m.matched == {"ready to go", r"port \d+$"}


def test_bytes_that_are_not_utf8_and_endless_lines_are_matched_without_holding_memory(monkeypatch):
    monkeypatch.setattr(outputwatch, "LINE_MAX", 10)
    m = LineMatcher()
    m.want("ok")
    m.feed(b"\xff\xfe" + b"x" * 20)
    assert m._tail == b"" and m.matched == set()
    m.feed(b"\xffok\n")
    assert m.matched == {"ok"}


def test_a_file_is_read_as_it_grows_and_again_from_its_start_when_replaced(tmp_path):
    path = str(tmp_path / "driver-2-stdout.log")
    f = OutputFollower(path)
    f.matcher.want("^ready$")
    f.read()  # (no file yet: the node has not started)
    with open(path, "ab") as out:
        out.write(b"booting\nrea")
        out.flush()
        f.read()
        assert f.matcher.matched == set()
        out.write(b"dy\n")
    f.read()
    assert f.matcher.matched == {"^ready$"}
    # rotated (a new file in its place): read from the start, its half line is not joined to the old one
    f.matcher.want("^again$")
    os.rename(path, path + ".1")
    with open(path, "wb") as out:
        out.write(b"again\n")
    f.read()
    assert f.matcher.matched == {"^ready$", "^again$"}
