"""`launcher logs` writes all of what it read, whatever its stdout takes at once."""

from __future__ import annotations

import fcntl
import io
import os
import signal
import sys
import threading
import time

from launcher.operate import logs
from tests.helpers import start_reading

F_SETPIPE_SZ = 1031


def test_a_write_a_signal_cut_short_is_finished_on_an_unbuffered_stdout(monkeypatch):
    # under PYTHONUNBUFFERED=1 stdout's binary layer is the raw descriptor: a signal (a stop and fg, too) while a
    # write waits for a full terminal ends it with part taken, and only the count says so
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, F_SETPIPE_SZ, 4096)
    monkeypatch.setattr(sys, "stdout", io.TextIOWrapper(io.FileIO(write_end, "w"), write_through=True))
    got = bytearray()
    reader = start_reading(read_end, got, 4096, 0.0005)
    interrupted = []
    old = signal.signal(signal.SIGUSR1, lambda *_: interrupted.append(1))
    sent = b"".join(b"line %06d of a node's output\n" % i for i in range(40000))
    writer = threading.Thread(target=logs._write, args=(sent,), daemon=True)
    try:
        writer.start()
        deadline = time.monotonic() + 60
        while writer.is_alive() and time.monotonic() < deadline:
            try:
                signal.pthread_kill(writer.ident, signal.SIGUSR1)
            except ProcessLookupError:  # (it ended between the look and the signal)
                break
            time.sleep(0.001)
        writer.join(1)
        assert not writer.is_alive(), "the write never ended"
    finally:
        signal.signal(signal.SIGUSR1, old)
        sys.stdout.close()
    reader.join(30)
    assert interrupted, "no signal reached the writing thread"
    assert bytes(got) == sent, "%d of %d bytes reached the pipe" % (len(got), len(sent))
