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


class Recorder:
    """console.relay's place: each hand-over as it was given (the relay's slices), and a yes."""

    def __init__(self) -> None:
        self.given: list[bytes] = []

    def __call__(self, stream, data: bytes) -> bool:
        self.given.append(data)
        return True


def _relay(tmp_path, monkeypatch, journal_stream: bool = False):
    monkeypatch.setattr(screen.journal, "is_journal", lambda environ: journal_stream)
    monkeypatch.setattr(screen.journal, "shared_socket", lambda: None)
    recorder = Recorder()
    monkeypatch.setattr(console, "relay", recorder)
    loop = asyncio.new_event_loop()
    read_end, write_end = os.pipe()
    os.set_blocking(read_end, False)
    terminal = io.TextIOWrapper(io.BytesIO())
    relay = screen.ScreenOutput(loop, "node-1", [(read_end, terminal)], str(tmp_path / "copy.log"), truncate=True)
    return loop, relay, write_end, recorder


def _run(loop, seconds: float) -> None:
    loop.run_until_complete(asyncio.sleep(seconds))


def test_only_whole_lines_are_passed_on_and_no_byte_is_taken_line_by_line(tmp_path, monkeypatch):
    loop, relay, write_end, recorder = _relay(tmp_path, monkeypatch)
    before = dict(screen.counts)
    lines = b"".join(b"line %06d of the node\n" % i for i in range(20000))
    try:
        for at in range(0, len(lines), 777):  # writes that cut lines anywhere
            os.write(write_end, lines[at:at + 777])
            if at % (777 * 50) == 0:
                _run(loop, 0.001)
        os.close(write_end)
        _run(loop, 0.2)
        assert relay.closed
    finally:
        loop.close()
    assert b"".join(recorder.given) == lines
    assert all(piece.endswith(b"\n") for piece in recorder.given)  # each slice whole lines: no mid-line cut
    assert len(recorder.given) < 20000 // 10  # many lines a hand-over
    assert (tmp_path / "copy.log").read_bytes() == lines
    assert screen.counts["as_read"] - before["as_read"] == len(lines)
    assert screen.counts["by_line"] == before["by_line"]


def test_a_line_without_its_end_is_passed_on_after_a_moment(tmp_path, monkeypatch):
    loop, relay, write_end, recorder = _relay(tmp_path, monkeypatch)
    try:
        os.write(write_end, b"done.\nEnter a number: ")
        _run(loop, 0.02)
        assert recorder.given == [b"done.\n"]  # the prompt waits for its end a moment
        _run(loop, screen.PARTIAL_S + 0.1)
        assert recorder.given == [b"done.\n", b"Enter a number: "]  # then comes as it is
        os.write(write_end, b"42\nlast words")
        os.close(write_end)
        _run(loop, 0.05)
        assert relay.closed and recorder.given[2:] == [b"42\n", b"last words"]  # the end of the stream ends it
    finally:
        loop.close()


def test_the_journal_takes_the_lines_one_by_one_and_the_count_says_so(tmp_path, monkeypatch):
    loop, relay, write_end, recorder = _relay(tmp_path, monkeypatch, journal_stream=True)
    before = dict(screen.counts)
    try:
        os.write(write_end, b"[ERROR] [1.5]: bad\nplain")
        os.write(write_end, b" line\n")
        os.close(write_end)
        _run(loop, 0.05)
    finally:
        loop.close()
    assert b"".join(recorder.given) == b"<3>node-1: [ERROR] [1.5]: bad\n<6>node-1: plain line\n"
    assert screen.counts["by_line"] - before["by_line"] == len(b"[ERROR] [1.5]: bad\nplain line\n")
    assert screen.counts["as_read"] == before["as_read"]
    assert "line by line" in screen.relay_note()
