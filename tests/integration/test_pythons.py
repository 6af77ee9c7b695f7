"""The launcher installed and run on each Python a ROS 1 robot has (issue 32): 3.8 (Ubuntu 20.04, Noetic's platform,
the ros:noetic images) to 3.13, as a user installs it: a fresh venv outside the checkout, the checkout installed
with that venv's own pip, the commands run from the venv's bin in a directory of their own.

On 3.8 the wheel is also installed with Ubuntu 20.04's pip (20.0.2): the build backend and the metadata must
be ones it reads. The interpreters are the machine's (pyenv's on these machines: `pythonX.Y` on PATH); in CI a
missing one is a failure, never a skip.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import signal
import subprocess

import pytest

from helpers import ROOT, ROS_PATH, descendants, free_port, pid_alive, until
from running import RospyTalker, make_package, write_launch

SLEEPER = "#!/bin/sh\nexec sleep 1000\n"
RESPAWNING = 10


def _interpreter(version: str, ros_part_missing) -> str:
    """pythonX.Y as the system has it on PATH, or else pyenv's (whose shim runs only the selected versions)."""
    candidates = [shutil.which("python" + version)]
    pyenv = shutil.which("pyenv")
    if pyenv:
        root = subprocess.run([pyenv, "root"], capture_output=True, text=True, timeout=60).stdout.strip()
        candidates += sorted(glob.glob(os.path.join(root, "versions", version + ".*", "bin", "python" + version)))
    for found in filter(None, candidates):
        r = subprocess.run([found, "-c", "import sys; print(sys.executable)"], capture_output=True, text=True,
                           timeout=60)
        if r.returncode == 0:
            return r.stdout.strip()
    ros_part_missing("no python%s here (neither on PATH nor among pyenv's versions)" % version)
    raise AssertionError("unreachable")


def _venv(python: str, where: str) -> str:
    """A venv made by `python` itself (its own pip), outside the checkout. Its bin is never put on PATH: the
    commands run through their own first line, the nodes' `#!/usr/bin/env python3` finds Debian's."""
    subprocess.run([python, "-m", "venv", where], check=True, timeout=300)
    return os.path.join(where, "bin")


def _pip(bin_dir: str, *args: str, cwd: str) -> str:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PIP_REQUIRE")) and k != "VIRTUAL_ENV"}
    r = subprocess.run([os.path.join(bin_dir, "python"), "-m", "pip", "--disable-pip-version-check", *args],
                       capture_output=True, text=True, timeout=900, cwd=cwd, env=env)
    assert r.returncode == 0, "pip %s failed:\n%s\n%s" % (" ".join(args), r.stdout[-3000:], r.stderr[-3000:])
    return r.stdout


def _run_a_fleet(bin_dir: str, tmp: str) -> None:
    """A rospy talker and ten respawning nodes run by this venv's `launch`: all ten SIGKILLed at once come back
    with new pids, `launcher status --json` lists them, `launcher bag record` records the talker and `launcher bag
    info` reads the bag, SIGINT ends it all with status 0."""
    work = os.path.join(tmp, "work")  # not the checkout: the installed package, not the source tree, runs
    os.makedirs(work)
    ws = os.path.join(tmp, "ws")
    make_package(ws, "py_pkg", {"talker": RospyTalker, "sleeper": SLEEPER})
    body = ['<node pkg="py_pkg" type="talker" name="talker"/>']
    body += ['<node pkg="py_pkg" type="sleeper" name="s%d" respawn="true"/>' % i for i in range(RESPAWNING)]
    launch_file = write_launch(work, "\n".join(body))
    port = free_port()
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("PYTHON", "ROS_")) and k not in ("VIRTUAL_ENV", "PYENV_VERSION")}
    env.update(PATH=ROS_PATH, ROS_PACKAGE_PATH=ws, ROS_HOME=os.path.join(tmp, "home"), ROS_IP="127.0.0.1",
               ROS_MASTER_URI="http://127.0.0.1:%d/" % port)
    out = open(os.path.join(tmp, "launch.out"), "wb")
    launch = subprocess.Popen([os.path.join(bin_dir, "launch"), launch_file], cwd=work, env=env,
                              stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    launcher = os.path.join(bin_dir, "launcher")

    def status() -> dict:
        """name -> node, from `launcher status --json`; {} until the launch answers"""
        r = subprocess.run([launcher, "status", "--json"], cwd=work, env=env, capture_output=True, text=True,
                           timeout=60)
        return {n["name"]: n for n in json.loads(r.stdout)["nodes"]} if r.returncode == 0 else {}

    def log() -> str:
        with open(out.name, errors="replace") as f:
            return f.read()

    try:
        sleepers = ["/s%d" % i for i in range(RESPAWNING)]

        def all_running() -> dict | None:
            assert launch.poll() is None, log()
            nodes = status()
            ok = all(nodes.get(n, {}).get("state") == "running" and nodes[n].get("pid") for n in sleepers + ["/talker"])
            return nodes if ok else None

        before = until(all_running, 60, 0.2, what="the talker and ten sleepers running")
        old = {n: before[n]["pid"] for n in sleepers}
        for pid in old.values():
            os.kill(pid, signal.SIGKILL)

        def respawned() -> dict | None:
            nodes = all_running()
            return nodes if nodes and all(nodes[n]["pid"] != old[n] for n in sleepers) else None

        after = until(respawned, 30, 0.2, what="ten sleepers back with new pids")
        assert all(pid_alive(after[n]["pid"]) for n in sleepers)
        assert not any(pid_alive(p) for p in old.values())

        bag = os.path.join(work, "chatter.bag")
        r = subprocess.run([launcher, "bag", "record", "-O", bag, "--duration", "2", "/chatter"], cwd=work, env=env,
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr
        r = subprocess.run([launcher, "bag", "info", "-y", "-k", "topics", bag], cwd=work, env=env,
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr
        assert "/chatter" in r.stdout and "std_msgs/String" in r.stdout, r.stdout
        messages = int(r.stdout.split("messages:")[1].split()[0])
        assert messages >= 10, r.stdout  # 20 Hz for 2 s

        nodes = set(descendants(launch.pid))
        launch.send_signal(signal.SIGINT)
        assert launch.wait(30) == 0, log()
        until(lambda: not any(pid_alive(p) for p in nodes), 10, what="nothing of the launch left")
    finally:
        if launch.poll() is None:
            launch.kill()
            launch.wait()
        out.close()


@pytest.mark.integration
@pytest.mark.parametrize("version", ["3.8", "3.9", "3.12", "3.13"])
def test_installed_and_run_on(version, tmp_path, ros_env, ros_part_missing):
    python = _interpreter(version, ros_part_missing)
    bin_dir = _venv(python, str(tmp_path / "venv"))
    _pip(bin_dir, "install", "-q", ROOT, cwd=str(tmp_path))
    _run_a_fleet(bin_dir, str(tmp_path / "run"))


@pytest.mark.integration
def test_the_wheel_installs_with_ubuntu_2004s_pip(tmp_path, ros_env, ros_part_missing):
    """Ubuntu 20.04's python3-pip is pip 20.0.2: the wheel built on 3.8 installs with it and runs."""
    python = _interpreter("3.8", ros_part_missing)
    builder = _venv(python, str(tmp_path / "builder"))
    _pip(builder, "wheel", "-q", "--no-deps", "-w", str(tmp_path / "dist"), ROOT, cwd=str(tmp_path))
    wheel = [str(p) for p in (tmp_path / "dist").glob("ros1_launcher-*.whl")]
    assert len(wheel) == 1, os.listdir(str(tmp_path / "dist"))
    bin_dir = _venv(python, str(tmp_path / "venv"))
    _pip(bin_dir, "install", "-q", "pip==20.0.2", cwd=str(tmp_path))
    assert _pip(bin_dir, "--version", cwd=str(tmp_path)).startswith("pip 20.0.2 ")
    _pip(bin_dir, "install", "-q", wheel[0], cwd=str(tmp_path))
    _run_a_fleet(bin_dir, str(tmp_path / "run"))
