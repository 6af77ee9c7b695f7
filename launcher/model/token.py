"""The run's secret: who may start, stop and restart its nodes.

Reading a launch's state is open, like the rest of a ROS graph. Changing it
needs the token written at start into the run's log directory, in a file
only its user can read (mode 0600); `launcher` reads it from there. The
token is compared in constant time.
"""

from __future__ import annotations

import os

TOKEN_FILE = "launcher-token"
REFUSED = 2  # the faultCode of a start/stop/restart call without the token


def create(run_dir: str) -> tuple[str, str]:
    """A new token, written to `<run_dir>/launcher-token` (0600, replacing an older one); (token, path).

    OSError when it cannot be written: the caller says so and control stays closed.
    """
    token = os.urandom(16).hex()  # (secrets.token_hex(16); secrets imports hmac: below)
    path = os.path.join(run_dir, TOKEN_FILE)
    tmp = "%s.%d" % (path, os.getpid())
    # created 0600 from the start (no window where another user could read it), then renamed over
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o600)
    try:
        os.write(fd, (token + "\n").encode("ascii"))
    finally:
        os.close(fd)
    os.replace(tmp, path)
    return token, path


def read(path: str) -> str:
    """The token in a token file; OSError if it cannot be read (not ours, gone)."""
    with open(path, encoding="ascii", errors="replace") as f:
        return f.read().strip()


def matches(expected: str, given: object) -> bool:
    import hmac  # here, when a call asks: hmac loads libcrypto, ~4 MB a launch would keep for this
    return bool(expected) and isinstance(given, str) and hmac.compare_digest(expected.encode(), given.encode())
