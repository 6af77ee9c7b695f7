"""TCP connections to a host by name, without the "idna" codec.

Python encodes a host name given as str with the "idna" codec at every
getaddrinfo (in the socket module's C code), and that codec imports
`encodings.idna`, `stringprep` and `unicodedata`: 0.7 MB that a launch keeps
for its whole run, for names (this machine's hostname in every node's URI,
localhost in the master's) that are ASCII and leave the codec unchanged. A
name given as bytes skips the codec. So an ASCII name is looked up as bytes
(`lookup_name`), in the loop's executor as asyncio does it, and each address
it has is tried in turn (`connect`), as asyncio's own `create_connection`
tries them; a numeric address and a name that is not ASCII go to asyncio as
they are. The addresses of a name are kept for a second (`KEPT_S`): a start's
burst of calls to one host is one lookup, not a worker thread each.
"""

from __future__ import annotations

import socket
import time
from typing import Any, Callable


def lookup_name(host: str) -> str | bytes:
    """`host` as getaddrinfo is to be given it: bytes for an ASCII name (the codec would return the same bytes),
    else the name itself (the codec's work)."""
    try:
        return host.encode("ascii")
    except UnicodeEncodeError:
        return host


def _numeric(host: str) -> bool:
    for family in (socket.AF_INET, socket.AF_INET6):
        try:
            socket.inet_pton(family, host)
            return True
        except (OSError, ValueError):
            pass
    return False


async def connect(loop: Any, factory: Callable[[], Any], host: str, port: int) -> tuple[Any, Any]:
    """`loop.create_connection(factory, host, port)`: (transport, protocol); OSError if no address of `host`
    takes the connection (asyncio's words when they failed differently). A name's addresses looked up within
    the last KEPT_S are used again; if none takes the connection, the name is looked up once more."""
    name = lookup_name(host)
    if isinstance(name, str) or _numeric(host):
        return await loop.create_connection(factory, host, port)
    kept = _kept.get(name)
    fresh = kept is None or kept[0] < time.monotonic()
    infos = await _look_up(loop, name) if fresh else kept[1]
    try:
        return await _connect_any(loop, factory, host, port, infos)
    except OSError:
        if fresh:
            raise
        _kept.pop(name, None)  # (the name may have moved: asked again, once)
        again = await _look_up(loop, name)
        if again == infos:
            raise
        return await _connect_any(loop, factory, host, port, again)


# A name's addresses, kept a moment: a start registers a hundred nodes at this machine's name within a second, and
# the master calls back a thousand subscribers, each a lookup in a worker thread (a burst of them starts up to six
# threads, 0.25 MB each) for the same answer. A lookup in flight is shared by every call that asks meanwhile.
KEPT_S = 1.0
_kept: dict[bytes, tuple[float, list]] = {}  # name -> (until when, its addresses)
_asked: dict[bytes, Any] = {}  # name -> the future of its lookup in flight


async def _look_up(loop: Any, name: bytes) -> list:
    import asyncio  # (loaded by then: this module is imported before the loop, for call_blocking)
    asked = _asked.get(name)
    if asked is None or asked.get_loop() is not loop:
        asked = _asked[name] = loop.run_in_executor(None, socket.getaddrinfo, name, None, 0, socket.SOCK_STREAM)
        asked.add_done_callback(lambda done: _answered(name, done))
    return await asyncio.shield(asked)  # (a call cancelled stops its own wait, not the others')


def _answered(name: bytes, done: Any) -> None:
    if _asked.get(name) is done:
        del _asked[name]
    if not done.cancelled() and done.exception() is None:
        _kept[name] = (time.monotonic() + KEPT_S, done.result())


async def _connect_any(loop: Any, factory: Callable[[], Any], host: str, port: int, infos: list) -> tuple[Any, Any]:
    errors: list[OSError] = []
    for family, kind, proto, _, address in infos:
        sock = socket.socket(family, kind, proto)
        try:
            sock.setblocking(False)
            await loop.sock_connect(sock, (address[0], port) + tuple(address[2:]))
        except OSError as e:
            sock.close()
            errors.append(e)
            continue
        except BaseException:  # (cancelled, or a timeout around the call: the socket goes with it)
            sock.close()
            raise
        return await loop.create_connection(factory, sock=sock)
    if not errors:
        raise OSError("no address of %s" % host)
    if len(errors) == 1 or len({str(e) for e in errors}) == 1:
        raise errors[0]
    raise OSError("Multiple exceptions: %s" % ", ".join(str(e) for e in errors))
