"""Starting one process: the working directory is created on demand, failures say what failed."""

from __future__ import annotations

import os

import pytest

from launcher.plan.command import NodeCommand
from launcher.plan.specs import ProcessSpec
from launcher.process.spawn import SpawnError, spawn


def test_missing_working_directory_is_created(tmp_path):
    work = tmp_path / "a" / "b"
    out = tmp_path / "pwd.txt"
    p = spawn(ProcessSpec("w-1", NodeCommand(["/bin/sh", "-c", "pwd > %s" % out], dict(os.environ), cwd=str(work))))
    assert p.wait(10) == 0
    assert out.read_text().strip() == str(work)


def test_missing_executable_is_reported_even_when_the_directory_was_missing_too(tmp_path):
    work = tmp_path / "new"
    with pytest.raises(SpawnError) as e:
        spawn(ProcessSpec("ghost-1", NodeCommand([str(tmp_path / "no_such_exe")], dict(os.environ), cwd=str(work))))
    assert "no_such_exe" in str(e.value) and "ghost-1" in str(e.value)
    assert work.is_dir()


def test_working_directory_that_cannot_be_made_is_a_spawn_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(SpawnError):
        spawn(ProcessSpec("x-1", NodeCommand(["/bin/true"], dict(os.environ), cwd=str(blocker / "sub"))))


def test_a_node_with_the_launchers_environment_inherits_it_and_another_gets_its_own(tmp_path):
    from launcher.process import spawn as spawn_module
    node_environ = spawn_module.node_environ
    spawn_module._OWN_ENVIRON.clear()  # (pytest changes PYTEST_CURRENT_TEST between tests; a launch never changes it)
    own = dict(os.environ)
    assert node_environ(own, []) is None  # (nothing to encode at its start: exec passes ours on)
    changed = dict(own, ROS_NAMESPACE="/ns")
    assert node_environ(changed, [("ROS_NAMESPACE", "/ns")]) is changed
    fewer = dict(own)
    fewer.pop("HOME", None)
    assert node_environ(fewer, []) is fewer  # (a variable of ours it must not have: not inherited)
    out = tmp_path / "env.txt"
    for env, changes in ((own, []), (changed, [("ROS_NAMESPACE", "/ns")])):
        p = spawn(ProcessSpec("e-1", NodeCommand(["/bin/sh", "-c", "env > %s" % out], env, changes)))
        assert p.wait(10) == 0
        seen = dict(line.split("=", 1) for line in out.read_text().splitlines() if "=" in line)
        assert all(seen.get(k) == v for k, v in env.items() if "\n" not in v)
        assert ("ROS_NAMESPACE" in seen) == ("ROS_NAMESPACE" in env)


def test_a_process_started_without_popen_answers_as_popen_does():
    """Spawned (a node started through libc before 3.10) gives the runners Popen's poll, wait and returncode."""
    import signal
    import subprocess
    import sys

    from launcher.process.spawn import Spawned

    run = Spawned(os.posix_spawn("/bin/sh", ["sh", "-c", "sleep 0.3; exit 4"], dict(os.environ)))
    assert run.poll() is None and run.returncode is None
    with pytest.raises(subprocess.TimeoutExpired):
        run.wait(0.05)
    assert run.wait(10) == 4 and run.poll() == 4 and run.returncode == 4
    killed = Spawned(os.posix_spawn(sys.executable, [sys.executable, "-c", "import time; time.sleep(30)"],
                                    dict(os.environ)))
    os.kill(killed.pid, signal.SIGKILL)
    assert killed.wait() == -signal.SIGKILL
    assert Spawned(killed.pid).poll() == 0  # (a pid reaped already: 0, as Popen says)


def test_a_nul_in_a_nodes_command_or_environment_fails_that_node_by_name(tmp_path):
    """An $(eval) can put a NUL in a node's args or env; no exec takes one. The node fails with its name (the
    launch goes on), as a missing executable does, on every Python's way of starting it."""
    for argv, env in ((["/bin/true", "a\0b"], dict(os.environ)), (["/bin/true"], dict(os.environ, BAD="x\0y"))):
        with pytest.raises(SpawnError) as e:
            spawn(ProcessSpec("nul-1", NodeCommand(argv, env, [("BAD", "x")], cwd=str(tmp_path))))
        assert "[nul-1]" in str(e.value) and "NUL" in str(e.value)
