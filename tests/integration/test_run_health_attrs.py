"""The health attributes as a user writes them in a launch file, run by `launch` with real processes."""

from __future__ import annotations

import xmlrpc.client

from helpers import free_port, until
from running import Launcher, make_package, ros_env, write_launch

# allocates 64 MiB and keeps it
Hog = """#!/usr/bin/env python3
import time
block = bytearray(64 << 20)
for i in range(0, len(block), 4096):
    block[i] = 1
time.sleep(1000)
"""


def test_wait_for_in_a_launch_file_holds_the_node_until_the_param_is_set(tmp_path):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "attrs", {"sleeper": "#!/bin/sh\nexec sleep 1000\n"})
    port = free_port()
    launch = write_launch(str(tmp_path), """
      <group wait_for="param:/go" wait_timeout="60">
        <node pkg="attrs" type="sleeper" name="held"/>
      </group>
      <node pkg="attrs" type="sleeper" name="free"/>""")
    lp = Launcher([launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        lp.wait_output(r"process\[free-\d+\]: started with pid")
        assert "process[held" not in lp.stdout  # still held: nothing has set /go
        xmlrpc.client.ServerProxy("http://127.0.0.1:%d/" % port).setParam("/test", "/go", True)
        lp.wait_output(r"process\[held-\d+\]: started with pid")
    finally:
        lp.close()


def test_memory_limit_restart_in_a_launch_file(tmp_path):
    pkgs = str(tmp_path / "pkgs")
    make_package(pkgs, "attrs", {"hog": Hog})
    port = free_port()
    launch = write_launch(str(tmp_path), '<node pkg="attrs" type="hog" name="hog" memory_limit="32MiB" '
                                         'on_limit="restart"/>')
    lp = Launcher(["--monitor-period", "0.2", launch], ros_env(str(tmp_path), port, pkgs), str(tmp_path))
    try:
        first = int(lp.wait_output(r"process\[hog-\d+\]: started with pid \[(\d+)\]").group(1))
        until(lambda: any(pid != first for pid in lp.started_pids().values()), 60, what="hog restarted")
        # (the limit's words are on stderr, the restart's on stdout: the two are read apart)
        until(lambda: "memory" in (lp.stdout + lp.stderr).lower(), 30, what="the memory limit said")
    finally:
        lp.close()
