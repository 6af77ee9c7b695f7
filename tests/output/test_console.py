"""The console with a blocked output: node output waits (the relay is told to pause, then to go on), launcher
lines are dropped past the bound and counted."""

from __future__ import annotations

import fcntl
import os
import sys
import threading

from launcher.output import console

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

        def read() -> None:
            while True:
                data = os.read(read_end, 65536)
                if not data:
                    return
                got.extend(data)
        reader = threading.Thread(target=read, daemon=True)
        reader.start()
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
