"""Node output for the journal: `<priority>node: line`, whole lines only, priority from the ROS level or the stream."""

from __future__ import annotations

import os

from launcher.output import journal


def test_lines_framed_with_priority_and_node_whole_lines_only():
    out = journal.LineFramer("talker-1", stderr=False)
    assert out.feed(b"[INFO] [1700000000.1]: hel") == b""
    assert out.feed(b"lo\n[ WARN] [1700000000.2]: w\nplain\r\n[ERR") == (
        b"<6>talker-1: [INFO] [1700000000.1]: hello\n<4>talker-1: [ WARN] [1700000000.2]: w\n<6>talker-1: plain\n")
    assert out.end() == b"<6>talker-1: [ERR\n"
    assert out.end() == b""
    err = journal.LineFramer("talker-1", stderr=True)
    assert err.feed(b"Traceback (most recent call last):\n\x1b[31m[FATAL] [1.0]: x\x1b[0m\n") == (
        b"<3>talker-1: Traceback (most recent call last):\n<2>talker-1: \x1b[31m[FATAL] [1.0]: x\x1b[0m\n")


def test_journal_stream_is_recognised_by_device_and_inode(tmp_path):
    path = tmp_path / "out"
    with open(path, "w") as f:
        st = os.fstat(f.fileno())
        assert journal.is_journal({"JOURNAL_STREAM": "%d:%d" % (st.st_dev, st.st_ino)}, f.fileno())
        assert not journal.is_journal({"JOURNAL_STREAM": "%d:%d" % (st.st_dev, st.st_ino + 1)}, f.fileno())
        assert not journal.is_journal({}, f.fileno())
