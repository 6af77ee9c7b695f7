"""`launch --core` under a connection flood, with a lowered open-file limit (a real process and sockets)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import xmlrpc.client

import pytest

from launcher.net import open_files

from helpers import ROOT, free_port, post_once, still_running, until


def _get_pid(port: int, timeout: float) -> int:
    """One legitimate call on its own connection, bounded by `timeout`."""
    reply = post_once(port, xmlrpc.client.dumps(("/legit",), "getPid").encode(), timeout)
    code, _msg, pid = xmlrpc.client.loads(reply.partition(b"\r\n\r\n")[2])[0][0]
    assert code == 1
    return pid


def test_connection_cap_leaves_room_below_the_open_file_limit():
    assert open_files.connection_cap(1024) < 1024 // 2
    assert open_files.connection_cap(256) >= 16
    assert open_files.connection_cap(10**7) == open_files.MAX_CONNECTIONS


def test_raise_open_file_limit_raises_the_soft_limit_to_the_hard_one():
    code = ("import resource; from launcher.net.open_files import raise_open_file_limit as r; "
            "n = r(); print(n, resource.getrlimit(resource.RLIMIT_NOFILE)[0])")
    out = subprocess.run(["prlimit", "--nofile=100:300", sys.executable, "-c", code], cwd=ROOT,
                         capture_output=True, text=True, check=True, env=dict(os.environ, PYTHONPATH=ROOT))
    assert out.stdout.split() == ["300", "300"]


@pytest.mark.parametrize("slow_clients", [400])
def test_slow_clients_beyond_the_open_file_limit_do_not_lock_out_legitimate_calls(slow_clients):
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(os.environ, PYTHONPATH=ROOT, ROS_MASTER_URI=uri, ROS_IP="127.0.0.1")
    env.pop("ROS_HOSTNAME", None)
    # 256 files for the whole master: fewer than the slow clients (its cap derives from this)
    proc = subprocess.Popen(["prlimit", "--nofile=256:256", sys.executable, "-m", "launcher", "--core",
                             "-p", str(port)], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    slow: list[socket.socket] = []
    try:
        pid = until(lambda: still_running(proc) and _get_pid(port, 1.0), 15, 0.05, what="master up", errors=(OSError,))
        latencies = []
        for i in range(slow_clients):
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.sendall(b"POST / HTTP/1.1\r\nHost: x\r\nContent-Le")  # a head that never ends
            slow.append(s)
            if i % 20 == 19:  # legitimate calls all along the flood
                t0 = time.monotonic()
                assert _get_pid(port, 1.0) == pid
                latencies.append(time.monotonic() - t0)
        for _ in range(10):
            t0 = time.monotonic()
            assert _get_pid(port, 1.0) == pid
            latencies.append(time.monotonic() - t0)
        assert max(latencies) < 1.0
    finally:
        for s in slow:
            s.close()
        proc.terminate()
        _out, err = proc.communicate(timeout=15)
    # at most a warning, not a traceback per failed accept
    assert len(err.splitlines()) < 10, err.decode(errors="replace")[:2000]
