"""README's everyday install, tried as a new user does, and the venv trap it used to set for rospy nodes.

A node script that starts with `#!/usr/bin/env python3` (most rospy nodes)
runs the first python3 on PATH. A virtual environment's `bin` there (README
once put the launcher's own venv first) gives it a python that cannot import
rospy: every such node died with "No module named 'rospy'". Here with a real
venv, Debian's rospy and real nodes.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import readme  # noqa: E402

from helpers import ROS_PATH, free_port, until  # noqa: E402
from running import Launcher, RospyTalker, make_package, master_proxy, stop_group, write_launch  # noqa: E402

ROOT = readme.ROOT
MISSING_EVERYWHERE = "#!/usr/bin/env python3\nimport no_such_module_anywhere\n"


def _publishers(port: int, topic: str) -> list[str]:
    try:
        code, _msg, (pubs, _subs, _srvs) = master_proxy(port).getSystemState("/test")
    except OSError:
        return []
    return next((nodes for t, nodes in pubs if t == topic), []) if code == 1 else []


def test_a_rospy_node_run_by_a_venvs_python3_is_explained_in_one_line(tmp_path, ros_env):
    """Two rospy talkers and a node importing a module no python has, with a real venv's bin first on PATH:
    all three die at once; `launch` says once that the venv's python3 is not the system's, which has rospy
    (nothing about the module that no python has)."""
    venv = tmp_path / "venv"
    subprocess.run([ros_env["python"], "-m", "venv", "--without-pip", str(venv)], check=True)
    make_package(str(tmp_path / "ws"), "trap_pkg", {"talker": RospyTalker, "other": MISSING_EVERYWHERE})
    launch = write_launch(str(tmp_path), '<node pkg="trap_pkg" type="other" name="other"/>\n'
                          '<node pkg="trap_pkg" type="talker" name="talker"/>\n'
                          '<node pkg="trap_pkg" type="talker" name="talker2" output="screen"/>')
    port = free_port()
    env = dict(os.environ, PATH="%s:%s" % (venv / "bin", ROS_PATH), ROS_PACKAGE_PATH=str(tmp_path / "ws"),
               ROS_HOME=str(tmp_path / "home"), ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_IP="127.0.0.1")
    env.pop("ROS_LOG_DIR", None)
    env.pop("ROS_NAMESPACE", None)
    lp = Launcher([launch], env, str(tmp_path))
    try:
        until(lambda: lp.stderr.count("process has died") == 3, 60, what="the three nodes died")
        err = lp.stderr
        assert err.count("No module named 'rospy'") == 2 and "No module named 'no_such_module_anywhere'" in err
        hints = [line for line in err.splitlines() if "cannot import" in line]
        assert len(hints) == 1, err
        assert hints[0].startswith(("[talker-", "[talker2-")), hints
        assert ("cannot import rospy: python3 on PATH is %s/python3, not the system's %s which has it"
                % (venv / "bin", ros_env["python"])) in hints[0]
        assert "take %s off PATH" % (venv / "bin") in hints[0]
    finally:
        lp.close()


def test_the_everyday_install_in_readme_runs_rospy_nodes(tmp_path, ros_env):
    """README's "Installing for everyday use", run as written by a user whose home is fresh and whose python3
    is the system's, then `launch` by name with a rospy talker whose `#!/usr/bin/env python3` must find the
    system's python3: it publishes."""
    home = tmp_path / "home"
    home.mkdir()
    make_package(str(tmp_path / "ws"), "inst_pkg", {"talker": RospyTalker})
    launch = write_launch(str(tmp_path), '<node pkg="inst_pkg" type="talker" name="talker" required="true"/>')
    port = free_port()
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("PYTHON", "ROS_")) and k not in ("VIRTUAL_ENV", "PYENV_VERSION")}
    # pip's downloads stay where this machine keeps them (the new home has no cache)
    env.setdefault("PIP_CACHE_DIR", os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"),
                                                 "pip"))
    env.update(HOME=str(home), PATH=ROS_PATH, ROS_PACKAGE_PATH=str(tmp_path / "ws"),
               ROS_HOME=str(tmp_path / "roshome"), ROS_MASTER_URI="http://127.0.0.1:%d/" % port,
               ROS_IP="127.0.0.1")
    # ~/.local/bin: on PATH once it exists, by Debian's and Ubuntu's ~/.profile at the next login
    script = ("set -e\n%s\nexport PATH=\"$HOME/.local/bin:$PATH\"\nexec launch %s\n"
              % (readme.shell_block("Installing for everyday use"), launch))
    out, err = open(tmp_path / "out", "wb"), open(tmp_path / "err", "wb")
    proc = subprocess.Popen(["bash", "-c", script], cwd=ROOT, env=env, stdout=out, stderr=err,
                            stdin=subprocess.DEVNULL, start_new_session=True)

    def published():
        if proc.poll() is not None:
            raise AssertionError("the install or launch ended (%s):\n%s\n%s" % (
                proc.returncode, (tmp_path / "out").read_text()[-3000:], (tmp_path / "err").read_text()[-3000:]))
        return "/talker" in _publishers(port, "/chatter")

    try:
        until(published, 600, 0.5, what="the rospy talker publishing under README's install")
        assert "No module named" not in (tmp_path / "err").read_text()
    finally:
        stop_group(proc, 20)
        out.close()
        err.close()
