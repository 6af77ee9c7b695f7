"""A parameter value the master could not send back is refused at setParam (against `launch --core`)."""

from __future__ import annotations

import os
import subprocess
import sys
import xmlrpc.client

import pytest

from helpers import ROOT, free_port, post_once, still_running, until


@pytest.fixture
def core_uri():
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(os.environ, PYTHONPATH=ROOT, ROS_MASTER_URI=uri, ROS_IP="127.0.0.1")
    env.pop("ROS_HOSTNAME", None)
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "--core", "-p", str(port)], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        until(lambda: still_running(proc) and xmlrpc.client.ServerProxy(uri).getPid("/t"), 15, 0.05, what="master up",
              errors=(OSError,))
        yield uri
    finally:
        proc.terminate()
        proc.wait(15)


def _set_raw(uri: str, key: str, value_xml: str):
    """setParam with a hand-written value (xmlrpc.client itself refuses to send such values)."""
    body = ("<?xml version='1.0'?><methodCall><methodName>setParam</methodName><params>"
            "<param><value><string>/t</string></value></param>"
            "<param><value><string>%s</string></value></param>"
            "<param>%s</param></params></methodCall>" % (key, value_xml)).encode()
    reply = post_once(int(uri.rstrip("/").rsplit(":", 1)[1]), body, 5)
    return xmlrpc.client.loads(reply.partition(b"\r\n\r\n")[2])[0][0]


@pytest.mark.parametrize("value_xml", [
    "<value><i8>4294967296</i8></value>",
    "<value><struct><member><name>deep</name><value><array><data>"
    "<value><i8>-9000000000</i8></value></data></array></value></member></struct></value>",
    "<value><struct><member><name>n</name><value><nil/></value></member></struct></value>",
])
def test_unsendable_value_is_refused_and_the_tree_stays_readable(core_uri, value_xml):
    master = xmlrpc.client.ServerProxy(core_uri)
    assert master.setParam("/t", "/ok", 1)[0] == 1
    code, msg, _ = _set_raw(core_uri, "/ns/big", value_xml)
    assert code == -1 and "/ns/big" in msg and ("32-bit" in msg or "nil" in msg)
    assert master.getParam("/t", "/")[2]["ok"] == 1
    assert master.hasParam("/t", "/ns/big")[2] is False
    # values inside 32 bits, sent as <i8>, are still taken
    assert _set_raw(core_uri, "/ns/small", "<value><i8>2147483647</i8></value>")[0] == 1
    assert master.getParam("/t", "/ns")[2] == {"small": 2147483647}


def test_in_process_set_param_refuses_it_too():
    import asyncio

    from launcher.master.server import Master

    async def scenario():
        master = Master(host="127.0.0.1", port=0, environ={"ROS_IP": "127.0.0.1"})
        await master.start()
        try:
            master.set_param("/ok", 1)
            with pytest.raises(ValueError, match=r"\[/cfg\].*32-bit"):
                master.set_param("/cfg", {"deep": [1, 2**40]})
            with pytest.raises(ValueError, match="nil"):
                master.set_param("/none", None)
            import datetime  # (what YAML makes of 2015-01-01, which no XML-RPC marshaller writes)
            with pytest.raises(ValueError, match=r"\[/day\].*type date \(2015-01-01\).*quote it"):
                master.set_param("/day", {"when": [datetime.date(2015, 1, 1)]})
            master.set_param("/stamp", datetime.datetime(2015, 1, 1, 12, 30))  # (a dateTime.iso8601)
            from launcher.net.xmlrpc import call
            code, _msg, root = await call(master.uri, "getParam", "/t", "/")
            assert code == 1 and root["ok"] == 1 and "cfg" not in root and "none" not in root and "day" not in root
            assert str(root["stamp"]) == "20150101T12:30:00"
        finally:
            await master.stop()
    asyncio.run(scenario())


def test_launch_file_with_such_a_value_fails_cleanly(tmp_path):
    launch = tmp_path / "big.launch"
    launch.write_text('<launch><param name="big" value="4294967296"/></launch>')
    port = free_port()
    env = dict(os.environ, PYTHONPATH=ROOT, ROS_MASTER_URI="http://127.0.0.1:%d/" % port, ROS_IP="127.0.0.1",
               ROS_HOME=str(tmp_path))
    env.pop("ROS_HOSTNAME", None)
    out = subprocess.run([sys.executable, "-m", "launcher", str(launch)], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=30)
    assert out.returncode != 0
    assert "[/big]" in out.stderr + out.stdout and "32-bit" in out.stderr + out.stdout
    assert "Traceback" not in out.stderr and "internal error" not in out.stderr
