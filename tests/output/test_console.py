"""The console with a blocked output: node output waits (the relay is told to pause, then to go on), launcher
lines are dropped past the bound and counted."""

from __future__ import annotations

import fcntl
import io
import os
import pty
import select
import signal
import sys
import threading
import time
import tty

import pytest

from launcher.output import console
from tests.helpers import start_reading

F_SETPIPE_SZ = 1031


def test_node_output_is_never_dropped_and_the_relay_is_told_when_to_wait(monkeypatch):
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)
    stream = open(write_end, "w")
    monkeypatch.setattr(sys, "stdout", stream)
    chunks = []
    try:
        # nobody reads: the node's chunks queue up until the console says "wait"
        while True:
            chunk = (b"%06d" % len(chunks)) * 1000
            chunks.append(chunk)
            if not console.relay(stream, chunk):
                break
            assert len(chunks) < 1000, "the console never asked the node output to wait"
        assert sum(map(len, chunks)) > console.MAX_QUEUED_OUTPUT
        resumed = threading.Event()
        console.when_drained(resumed.set)
        assert not resumed.is_set()
        # launcher lines past their own bound are dropped (oldest first), node output stays
        for i in range(3000):
            console.printlog("launcher line %04d %s" % (i, "x" * 60))
        got = bytearray()
        reader = start_reading(read_end, got)
        assert console.flush(30)
        assert resumed.is_set()
    finally:
        console.forget(stream)
        stream.close()
    reader.join(10)
    assert not reader.is_alive(), "the pipe's reader never saw its end"
    text = bytes(got)
    assert text.startswith(b"".join(chunks))  # all of it, in order, before the lines queued after it
    assert b"launcher line 2999" in text and b"launcher line 0000" not in text
    assert b"console lines dropped while the output was blocked" in text
    os.close(read_end)


def relay_through(stream, read_end: int, disturb=None) -> tuple[bytes, bytes]:
    """Node output relayed to `stream` (the write end of a pipe of 4 KiB read slowly, so that the console's writes
    wait for it), `disturb()` called while it goes on: (what was relayed, what the pipe's reader got)."""
    chunks = [b"".join(b"line %06d of the flood\n" % (i * 1000 + j) for j in range(1000)) for i in range(40)]
    got = bytearray()
    reader = start_reading(read_end, got, 4096, 0.0005)
    try:
        for chunk in chunks:
            if not console.relay(stream, chunk):  # (the console is full: wait, as the relay does)
                drained = threading.Event()
                console.when_drained(drained.set)
                assert drained.wait(30), "the console never drained"
            if disturb is not None:
                disturb()
        assert console.flush(60)
    finally:
        console.forget(stream)
        stream.close()
    reader.join(30)
    assert not reader.is_alive(), "the pipe's reader never saw its end"
    os.close(read_end)
    return b"".join(chunks), bytes(got)


def unbuffered(fd: int):
    """What sys.stdout is under `python -u` or PYTHONUNBUFFERED=1: text written through to the raw descriptor."""
    return io.TextIOWrapper(io.FileIO(fd, "w"), write_through=True)


def test_a_write_a_signal_cut_short_is_finished_on_an_unbuffered_stdout():
    # the console's thread waits in a write to a full pipe; a signal there ends the write with part of it taken,
    # and the raw stream below the text layer says so only by its count (the rest was lost on the terminal)
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)
    interrupted = []
    old = signal.signal(signal.SIGUSR1, lambda *_: interrupted.append(1))

    def disturb() -> None:
        for thread in threading.enumerate():
            if thread.name == "console":
                for _ in range(20):
                    signal.pthread_kill(thread.ident, signal.SIGUSR1)
                    time.sleep(0.001)
    try:
        sent, got = relay_through(unbuffered(write_end), read_end, disturb)
    finally:
        signal.signal(signal.SIGUSR1, old)
    assert interrupted, "no signal reached the console's thread"
    assert got == sent, "%d of %d bytes reached the pipe" % (len(got), len(sent))


@pytest.mark.parametrize("make", [unbuffered, lambda fd: open(fd, "w")], ids=["unbuffered", "buffered"])
def test_node_output_waits_for_a_stdout_someone_made_non_blocking(make):
    # a non-blocking descriptor takes what fits, then nothing: a raw stream says None, a buffered one raises
    # BlockingIOError with what it took; the rest waits until the descriptor takes more
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)
    os.set_blocking(write_end, False)
    sent, got = relay_through(make(write_end), read_end)
    assert got == sent, "%d of %d bytes reached the pipe" % (len(got), len(sent))


def test_a_launcher_line_never_waits_for_a_terminal_with_room_for_less_than_the_line(monkeypatch):
    # a terminal nobody reads, with a little room: select calls it writable, and a 4 KiB line written to the
    # shared (blocking) descriptor would wait there, in the event loop's thread, until someone reads
    master, slave = pty.openpty()
    tty.setraw(slave)
    stream = open(slave, "w")
    monkeypatch.setattr(sys, "stdout", stream)
    os.set_blocking(slave, False)
    filled = 0
    while True:
        try:
            filled += os.write(slave, b"x" * 100)
        except BlockingIOError:
            break
    os.set_blocking(slave, True)
    got = bytearray()
    deadline = time.monotonic() + 30
    while not select.select((), (slave,), (), 0.05)[1]:  # (read a little at a time until it has some room)
        assert time.monotonic() < deadline, "the terminal never had room"
        got += os.read(master, 256)
    readers: list[threading.Thread] = []
    # (the terminal is read once the line was put, or after 10 s: a launch waiting there is caught, not hung)
    late = threading.Timer(10, lambda: readers.append(start_reading(master, got)))
    late.start()
    line = "launcher line " + "y" * 4000  # (at most PIPE_BUF: written from the caller when select said writable)
    try:
        console.printlog(line)
        late.cancel()
        late.join()
        assert not readers, "the launcher's line waited for the terminal's reader"
        readers.append(start_reading(master, got))
        console.printlog("the next line")
        assert console.flush(30)
    finally:
        late.cancel()
        console.forget(stream)
        stream.close()
    readers[-1].join(10)
    os.close(master)
    assert bytes(got) == b"x" * filled + (line + "\nthe next line\n").encode()
