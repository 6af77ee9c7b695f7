"""Node output for the journal: an entry per line with the node's fields on journald's native socket, else `<priority>node: line`
on the stream; whole lines only, priority from the ROS level or the stream."""

from __future__ import annotations

import io
import os
import socket

from launcher.output import console, journal


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


def test_a_native_entry_is_key_value_lines_and_a_value_with_a_newline_is_length_prefixed():
    assert journal.entry([("MESSAGE", b"hello"), ("PRIORITY", b"6")]) == b"MESSAGE=hello\nPRIORITY=6\n"
    assert journal.entry([("MESSAGE", b"a\nb")]) == b"MESSAGE\n" + (3).to_bytes(8, "little") + b"a\nb\n"


def test_framed_lines_become_one_entry_each_with_the_nodes_fields(tmp_path):
    """What journald's native socket receives: a datagram per line, the node's name as fields; a line the socket
    refuses (here: longer than an entry) goes to the stream, framed, instead of being lost."""
    path = str(tmp_path / "socket")
    reader = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    reader.bind(path)
    reader.settimeout(5)
    fallback = io.TextIOWrapper(io.BytesIO())
    framer = journal.LineFramer("", stderr=True)
    stream = journal.NativeStream(journal.native_socket(path), "cam/driver-2", "/cam/driver", fallback)
    # handed over as the screen relay does, to the console (which writes all of what a stream takes in part)
    assert console.relay(stream, framer.feed(b"[ WARN] [1.5]: hot\nplain on std"))
    assert console.relay(stream, framer.feed(b"err\n" + b"x" * (journal.MAX_ENTRY + 1) + b"\n"))
    assert console.flush(5)
    first, second = reader.recv(65536), reader.recv(65536)
    assert first == (b"MESSAGE=[ WARN] [1.5]: hot\nPRIORITY=4\n"
                     b"SYSLOG_IDENTIFIER=cam/driver-2\nROS_NODE=/cam/driver\n")
    assert second.startswith(b"MESSAGE=plain on stderr\nPRIORITY=3\n")
    assert fallback.buffer.getvalue() == b"<3>cam/driver-2: " + b"x" * (journal.MAX_ENTRY + 1) + b"\n"
    assert journal.native_socket(str(tmp_path / "absent")) is None
