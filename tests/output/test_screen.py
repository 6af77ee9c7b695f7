"""The relay of one node's terminal-bound output (output/screen.py), on real pipes."""

from __future__ import annotations

import asyncio
import fcntl
import io
import os

from launcher.output import console, screen

F_SETPIPE_SZ = 1031


def test_the_drain_at_exit_is_bounded_when_a_process_left_behind_keeps_writing(tmp_path, monkeypatch):
    monkeypatch.setattr(screen, "DRAIN_MAX", 2 * screen.CHUNK)  # (a pipe holds 1 MiB at most without privileges)
    loop = asyncio.new_event_loop()
    read_end, write_end = os.pipe()
    os.set_blocking(read_end, False)
    # what a node left in its group holds the stream and has written more than a drain takes at once
    size = fcntl.fcntl(read_end, F_SETPIPE_SZ, 1 << 20)
    assert size >= 2 * (screen.DRAIN_MAX + screen.CHUNK)
    os.write(write_end, b"y\n" * (size // 2))
    terminal = io.TextIOWrapper(io.BytesIO())
    copy = tmp_path / "copy.log"
    relay = screen.ScreenOutput(loop, "node-1", [(read_end, terminal)], str(copy), truncate=True)
    try:
        relay.drain()  # what the node wrote is relayed now; a leftover's endless output would hold the exit line
        assert screen.DRAIN_MAX <= copy.stat().st_size <= screen.DRAIN_MAX + screen.CHUNK
        assert not relay.closed  # still watched: the rest comes when the loop reads it
        os.close(write_end)  # the leftover ends: the loop relays the rest, up to the end of the stream

        async def until_closed() -> None:
            while not relay.closed:
                await asyncio.sleep(0.01)
        loop.run_until_complete(asyncio.wait_for(until_closed(), 10))
    finally:
        loop.close()
    assert copy.read_bytes() == b"y\n" * (size // 2)
    assert console.flush(10)  # (chunks larger than PIPE_BUF go through the console's thread)
    assert terminal.buffer.getvalue() == b"y\n" * (size // 2)
