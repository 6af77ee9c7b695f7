"""`<param command=...>`: run together once the launch is read, never when overwritten, errors at their own line."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import time

import pytest

from launcher.model.errors import LaunchError
from launcher.xml import load


def env(tmp_path):
    return {"PATH": os.environ["PATH"], "ROS_PACKAGE_PATH": str(tmp_path), "ROS_HOME": str(tmp_path / "home")}


def write(tmp_path, body):
    f = tmp_path / "robot.launch"
    f.write_text("<launch>\n%s\n</launch>\n" % body)
    return str(f)


def test_slow_commands_run_side_by_side(tmp_path):
    cmd = "sh -c 'sleep 1; echo %d'"
    f = write(tmp_path, "\n".join('<param name="d%d" command="%s"/>' % (i, cmd % i) for i in range(4)))
    t0 = time.monotonic()
    config = load([f], environ=env(tmp_path), core=False)
    took = time.monotonic() - t0
    assert [config.params["/d%d" % i].value for i in range(4)] == [0, 1, 2, 3]
    cores = os.cpu_count() or 1
    assert took < -(-4 // cores) + 1.0, took  # one after another would take 4 s


def test_a_command_whose_parameter_is_overwritten_never_runs(tmp_path):
    marker = tmp_path / "ran"
    f = write(tmp_path, '<param name="desc" command="touch %s"/>\n<param name="desc" value="plain"/>' % marker)
    config = load([f], environ=env(tmp_path), core=False)
    assert config.params["/desc"].value == "plain"
    assert not marker.exists()


@pytest.mark.parametrize("body", [
    '<param name="desc" type="float" command="touch {marker}"/>\n<param name="desc" value="plain"/>',
    '<param name="~desc" type="float" command="touch {marker}"/>',  # (a launch-level ~param no node follows)
    '<param name="desc" type="float" command="touch {marker}"/>',
    '<param name="desc" type=" " command="touch {marker}"/>',  # (the type '' to roslaunch)
], ids=["overwritten", "taken-by-no-node", "set", "blank"])
def test_an_unknown_type_is_refused_even_where_the_command_never_runs(tmp_path, body):
    # roslaunch runs each command as it reads it, then refuses the type: "Unknown type 'float'"
    marker = tmp_path / "ran"
    f = write(tmp_path, body.format(marker=marker))
    with pytest.raises(LaunchError) as e:
        load([f], environ=env(tmp_path), core=False)
    assert e.value.line == 2 and "Unknown type '%s'" % ("" if 'type=" "' in body else "float") in str(e.value)
    assert not marker.exists()


def test_the_first_failure_in_file_order_is_reported_at_its_own_line(tmp_path):
    f = write(tmp_path, '<param name="ok" command="echo fine"/>\n'
                        '<param name="slow_bad" command="sh -c \'sleep 0.5; exit 3\'"/>\n'
                        '<param name="fast_bad" command="sh -c \'exit 4\'"/>')
    with pytest.raises(LaunchError) as e:
        load([f], environ=env(tmp_path), core=False)
    assert e.value.line == 3 and "returned with code [3]" in str(e.value)


def test_private_command_param_of_a_node_gets_its_value(tmp_path):
    f = write(tmp_path, '<node pkg="p" type="t" name="n"><param name="model" type="yaml" command="echo {a: 1}"/></node>')
    config = load([f], environ=env(tmp_path), core=False)
    assert config.params["/n/model"].value == {"a": 1}


def test_a_terminal_sees_what_runs(tmp_path):
    f = write(tmp_path, "\n".join('<param name="slow%d" command="sleep 1.5"/>' % i for i in range(2)))
    primary, secondary = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "--dump-params", f], stdout=subprocess.PIPE,
                            stderr=secondary, env=env(tmp_path))
    os.close(secondary)
    out, _ = proc.communicate(timeout=60)
    seen = b""
    while True:
        try:
            chunk = os.read(primary, 4096)
        except OSError:
            break
        if not chunk:
            break
        seen += chunk
    os.close(primary)
    assert proc.returncode == 0 and b"/slow0: ''" in out
    assert b"running command parameters (0 of 2 done" in seen and b"slow0" in seen
