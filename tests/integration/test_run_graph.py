"""Without extension attributes a launch makes roslaunch's ROS graph: the nodes, topics, services and parameter
names Debian's roslaunch makes for the same file, plus only what README says where it makes that claim
(`/diagnostics`, published by `/launcher_diagnostics`; `--no-diagnostics` leaves roslaunch's graph exactly)."""

from __future__ import annotations

import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import readme  # noqa: E402

from helpers import ROS_PATH, free_port, until  # noqa: E402
from running import Launcher, RospyTalker, make_package, master_proxy, stop_group, write_launch  # noqa: E402
from running import ros_env as run_env  # noqa: E402

BODY = """
  <param name="greeting" value="hi"/>
  <node pkg="graph_pkg" type="talker" name="talker"/>
  <group ns="g"><node pkg="rostopic" type="rostopic" name="listener" args="echo /chatter"/></group>
"""


def _graph(port: int) -> dict[str, set]:
    """What the master knows: every (kind, name, node) registration, the node names and the parameter names
    (roslaunch's own key's port, which differs run to run, left out)."""
    m = master_proxy(port)
    _c, _m, (pubs, subs, srvs) = m.getSystemState("/test")
    regs = {(kind, name, node) for kind, entries in (("pub", pubs), ("sub", subs), ("srv", srvs))
            for name, nodes in entries for node in nodes}
    params = {re.sub(r"__\d+$", "__PORT", p) for p in m.getParamNames("/test")[2]}
    return {"registrations": regs, "nodes": {r[2] for r in regs}, "params": params}


def _settled(port: int, extra: set) -> dict[str, set] | None:
    """The graph once both nodes and rosout are fully registered (their logger services come last)."""
    try:
        g = _graph(port)
    except OSError:
        return None
    want = {("sub", "/chatter", "/g/listener"), ("pub", "/chatter", "/talker"), ("sub", "/rosout", "/rosout"),
            ("srv", "/talker/set_logger_level", "/talker"), ("srv", "/g/listener/set_logger_level", "/g/listener"),
            ("srv", "/rosout/set_logger_level", "/rosout")} | extra
    return g if want <= g["registrations"] else None


def test_the_graph_is_roslaunchs_but_for_what_readme_names(tmp_path, ros_env):
    pkg_root = str(tmp_path / "ws")
    make_package(pkg_root, "graph_pkg", {"talker": RospyTalker})
    launch = write_launch(str(tmp_path), BODY)
    graphs = {}
    for which, extra_args, extra in (("roslaunch", [], set()), ("ours", ["--no-diagnostics"], set()),
                                     ("ours-default", [], {("pub", "/diagnostics", "/launcher_diagnostics")})):
        port = free_port()
        env = run_env(str(tmp_path / which), port, pkg_root)
        env["PATH"] = ROS_PATH  # the rospy talker's `#!/usr/bin/env python3` is Debian's python3
        if which == "roslaunch":
            proc = subprocess.Popen(["roslaunch", launch, "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL, start_new_session=True)
            stop = lambda: stop_group(proc, 30)  # noqa: E731
        else:
            lp = Launcher([launch, "-p", str(port)] + extra_args, env, str(tmp_path))
            stop = lp.close
        try:
            graphs[which] = until(lambda: _settled(port, extra), 60, 0.2, what="%s's graph registered" % which)
        finally:
            stop()
    theirs, ours, default = graphs["roslaunch"], graphs["ours"], graphs["ours-default"]
    assert ours == theirs
    added = {k: default[k] - theirs[k] for k in theirs}
    assert all(not (theirs[k] - default[k]) for k in theirs), "the default graph lacks something of roslaunch's"
    named = {n for regs in added["registrations"] for n in regs[1:]} | added["nodes"] | added["params"]
    assert named, "the default graph adds nothing: README need not name anything"
    # README's claim, where it is made, names every addition and the option that removes them
    claim = next(p for p in readme.section("Supervising fleets").split("\n\n") if "as with roslaunch" in p)
    for name in sorted(named) + ["--no-diagnostics"]:
        assert "`%s`" % name in claim, "README's 'as with roslaunch' does not name %s" % name
