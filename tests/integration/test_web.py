"""The live view's page in a real browser: Debian's headless Chromium driven by Selenium loads the page of
`launch --web` running real rospy nodes, restarts one with the run's token, and reads the topics page; the
server's guards are checked with a raw HTTP client."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time

import pytest

from helpers import free_port, until
from running import Launcher, make_package, ros_env, write_launch

pytestmark = pytest.mark.integration

Talker = """#!/usr/bin/python3
import rospy
from std_msgs.msg import String
rospy.init_node("talker")
pub = rospy.Publisher("chatter", String, queue_size=1)
while not rospy.is_shutdown():
    pub.publish(String("hi"))
    rospy.sleep(0.3)
"""
Listener = """#!/usr/bin/python3
import rospy
from std_msgs.msg import String
rospy.init_node("listener")
rospy.Subscriber("chatter", String, lambda m: None)
rospy.spin()
"""
Warner = """#!/usr/bin/python3
import rospy
rospy.init_node("warner")
while not rospy.is_shutdown():
    rospy.loginfo("fine")
    rospy.logerr("broken")
    rospy.sleep(0.3)
"""
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


@pytest.fixture
def browser():
    webdriver = pytest.importorskip("selenium.webdriver") if not os.environ.get("REQUIRE_ROS") else \
        __import__("selenium.webdriver").webdriver
    if not (os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER)):
        if os.environ.get("REQUIRE_ROS"):
            pytest.fail("Debian's chromium and chromium-driver are missing (.ci/run installs them)")
        pytest.skip("Debian's chromium and chromium-driver are missing")
    from selenium.webdriver.chrome.service import Service
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM  # (Debian's: Selenium downloads nothing)
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1400,900"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    yield driver
    driver.quit()


def raw(port: int, request: bytes) -> bytes:
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(request)
        data = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                return data
            data += chunk


def status(env: dict) -> dict:
    r = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "status", "--json"], env=env, capture_output=True,
                       text=True, timeout=60)
    return json.loads(r.stdout) if r.returncode == 0 else {}


def test_the_page_shows_restarts_and_lists_topics_and_the_server_refuses_strangers(tmp_path, browser):
    make_package(str(tmp_path / "pkgs"), "web_tests", {"talker": Talker, "listener": Listener, "warner": Warner})
    env = ros_env(str(tmp_path), free_port(), str(tmp_path / "pkgs"))
    port = free_port()
    lp = Launcher(["--web", str(port), write_launch(str(tmp_path), """
      <node pkg="web_tests" type="talker" name="talker"/>
      <node pkg="web_tests" type="listener" name="listener"/>
      <node pkg="web_tests" type="warner" name="warner"/>
    """)], env, str(tmp_path))
    try:
        lp.wait_output("the live view of .* at http://127.0.0.1:%d/" % port, 60, stream="stderr")
        names = ["/talker", "/listener"]
        info = until(lambda: (lambda s: s if s and all(n["state"] == "running" for n in s["nodes"]) else None)(
            status(env)), 60, 0.2, what="nodes running")
        pids = {n["name"]: n["pid"] for n in info["nodes"]}
        from selenium.webdriver.common.by import By
        browser.get("http://127.0.0.1:%d/" % port)

        def page_pid(name: str) -> str:
            cells = browser.find_elements(By.CSS_SELECTOR, "tr[data-node='%s'] td.pid" % name)
            return cells[0].text if cells else ""
        until(lambda: all(page_pid(n) == str(pids[n]) for n in names), 30, 0.2, what="every row with its pid")
        assert "127.0.0.1:%d" % port in browser.find_element(By.ID, "bound").text
        # an output="log" node's ERROR lines from /rosout, tagged and in their level's colour; not its INFO
        until(lambda: any(e.text.startswith("[/warner] ERROR broken") for e in browser.find_elements(
            By.CSS_SELECTOR, "#output span.level-ERROR")), 30, 0.2, what="the log node's ERROR line, coloured")
        assert "fine" not in browser.find_element(By.ID, "output").text
        # restart /talker with the token: asked once, kept in the tab
        with open(info["token_file"]) as f:
            token = f.read().strip()
        browser.find_element(By.CSS_SELECTOR, "tr[data-node='/talker'] button[data-verb='restart']").click()
        alert = until(lambda: browser.switch_to.alert, 10, what="the token prompt")
        alert.send_keys(token)
        alert.accept()
        new = until(lambda: (lambda p: p if p.isdigit() and int(p) != pids["/talker"] else None)(page_pid("/talker")),
                    60, 0.2, what="the new pid in the page")
        st = {n["name"]: n for n in status(env)["nodes"]}
        assert st["/talker"]["pid"] == int(new) and st["/talker"]["restarts"] == 1
        # a page opened later gets the last samples at once (its sparklines are not empty)
        assert until(lambda: browser.find_elements(By.CSS_SELECTOR, "tr[data-node='/listener'] svg polyline"), 10,
                     0.2, what="a sparkline")
        def snapshot() -> dict:
            with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
                s.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)
                data = b""
                while b"\n\n" not in data.partition(b"\r\n\r\n")[2]:
                    data += s.recv(65536)
            return json.loads(data.partition(b"\r\n\r\n")[2].split(b"\n\n")[0].partition(b"data: ")[2])
        first = until(lambda: (lambda s: s if sum(1 for c, _ in s["history"].get("/listener", []) if c is not None)
                               >= 3 else None)(snapshot()), 20, 0.5, what="3 samples of /listener in a new page's "
                      "first event")
        assert first["type"] == "snapshot"
        # the topics page: from the master's registry
        browser.get("http://127.0.0.1:%d/#topics" % port)

        def chatter() -> list[str] | None:
            for tr in browser.find_elements(By.CSS_SELECTOR, "#topics tbody tr"):
                cells = [td.text for td in tr.find_elements(By.TAG_NAME, "td")]
                if cells and cells[0] == "/chatter" and cells[2]:  # (the restarted talker registers again)
                    return cells
            browser.refresh()
            return None
        cells = until(chatter, 30, 0.5, what="/chatter on the topics page")
        assert cells[1] == "std_msgs/String" and "/talker" in cells[2] and "/listener" in cells[3]
        shots = os.environ.get("LAUNCHER_SCREENSHOTS")  # (benchmarks/screenshots: the README's images)
        if shots:
            browser.get("http://127.0.0.1:%d/" % port)
            until(lambda: page_pid("/talker") == new, 30, 0.2, what="page again")
            browser.save_screenshot(os.path.join(shots, "web.png"))

        # a raw client: no token, a foreign Origin, a foreign Host (DNS rebinding): refused
        body = b'{"node": "/listener"}'
        post = b"POST /api/stop HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nContent-Length: %d\r\n%s\r\n" + body
        assert raw(port, post % (port, len(body), b"Connection: close\r\n")).startswith(b"HTTP/1.1 403")
        assert raw(port, post % (port, len(body), b"Connection: close\r\nX-Launcher-Token: %s\r\nOrigin: "
                                 b"http://evil.example\r\n" % token.encode())).startswith(b"HTTP/1.1 403")
        assert raw(port, b"GET / HTTP/1.1\r\nHost: evil.example:%d\r\nConnection: close\r\n\r\n" % port
                   ).startswith(b"HTTP/1.1 403")
        assert raw(port, post % (port, len(body), b"Connection: close\r\nX-Launcher-Token: wrong\r\n")
                   ).startswith(b"HTTP/1.1 403")
        assert {n["name"]: n["state"] for n in status(env)["nodes"]}["/listener"] == "running"
    finally:
        lp.close()


def test_the_reload_button_applies_the_changed_files(tmp_path, browser):
    make_package(str(tmp_path / "pkgs"), "web_tests", {"talker": Talker, "listener": Listener})
    env = ros_env(str(tmp_path), free_port(), str(tmp_path / "pkgs"))
    port = free_port()
    path = write_launch(str(tmp_path), '<node pkg="web_tests" type="talker" name="talker"/>')
    lp = Launcher(["--web", str(port), path], env, str(tmp_path))
    try:
        lp.wait_output("the live view of .* at http://127.0.0.1:%d/" % port, 60, stream="stderr")
        info = until(lambda: (lambda s: s if s and all(n["state"] == "running" for n in s["nodes"]) else None)(
            status(env)), 60, 0.2, what="talker running")
        talker = info["nodes"][0]["pid"]
        with open(path) as f:
            text = f.read()
        with open(path, "w") as f:
            f.write(text.replace("</launch>", '<node pkg="web_tests" type="listener" name="listener"/>\n</launch>'))
        from selenium.webdriver.common.by import By
        browser.get("http://127.0.0.1:%d/" % port)
        with open(info["token_file"]) as f:
            token = f.read().strip()
        browser.find_element(By.ID, "reload").click()
        alert = until(lambda: browser.switch_to.alert, 10, what="the token prompt")
        alert.send_keys(token)
        alert.accept()
        until(lambda: "reloaded: start /listener: new in the launch" in browser.find_element(By.ID, "message").text,
              30, 0.2, what="the reload's answer in the page")
        st = until(lambda: (lambda s: s if s.get("/listener", {}).get("state") == "running" else None)(
            {n["name"]: n for n in status(env)["nodes"]}), 60, 0.2, what="listener running")
        assert st["/talker"]["pid"] == talker
        until(lambda: browser.find_elements(By.CSS_SELECTOR, "tr[data-node='/listener']"), 30, 0.2,
              what="the new node's row in the page")
    finally:
        lp.close()


def test_a_page_of_launcher_web_attached_late_draws_the_last_minute_at_once(tmp_path, browser):
    """`launcher web` started beside a launch that has run a while: the sparklines start with the samples the
    launch kept, not empty."""
    import xmlrpc.client
    make_package(str(tmp_path / "pkgs"), "web_tests", {"talker": Talker, "listener": Listener})
    env = ros_env(str(tmp_path), free_port(), str(tmp_path / "pkgs"))
    lp = Launcher([write_launch(str(tmp_path), '<node pkg="web_tests" type="listener" name="listener"/>')], env,
                  str(tmp_path))
    web = None
    try:
        uri = until(lambda: status(env).get("uri"), 60, 0.2, what="the launch's server")

        def kept() -> int:
            code, _msg, text = xmlrpc.client.ServerProxy(uri).launcher_samples(True)
            return len(json.loads(text).get("/listener", []))
        until(lambda: kept() >= 8, 60, 0.5, what="8 samples kept by the launch")
        port = free_port()
        web = subprocess.Popen([sys.executable, "-m", "launcher.cli.tool", "web", str(port)], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        from selenium.webdriver.common.by import By

        def listening() -> bool:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                return True
            except OSError:
                return False
        until(listening, 30, 0.1, what="the page server")
        browser.get("http://127.0.0.1:%d/" % port)
        # the first drawing of the row: the CPU line (the first polyline) has the kept samples' points
        points = until(lambda: (lambda p: p if p else None)(browser.execute_script(
            "const p = document.querySelector(\"tr[data-node='/listener'] svg polyline\");"
            "return p ? p.getAttribute('points').split(' ').length : 0;")), 10, 0.05, what="the sparkline")
        assert points >= 8
    finally:
        if web is not None:
            web.terminate()
            web.wait(10)
        lp.close()


def test_the_pages_last_exit_shows_while_a_crash_looping_node_runs_again(tmp_path, browser):
    """A node exiting 3 every 0.5 s under respawn: its row's LAST EXIT reads `code 3` in every sample, while it
    runs again too; so does a page opened later (its first event, the snapshot, carries the last exit)."""
    make_package(str(tmp_path / "pkgs"), "web_tests", {"crasher": "#!/bin/sh\nsleep 0.5\nexit 3\n"})
    env = ros_env(str(tmp_path), free_port(), str(tmp_path / "pkgs"))
    port = free_port()
    lp = Launcher(["--web", str(port), write_launch(str(tmp_path), '<node pkg="web_tests" type="crasher" '
                                                    'name="crasher" respawn="true"/>')], env, str(tmp_path))
    try:
        lp.wait_output("the live view of .* at http://127.0.0.1:%d/" % port, 60, stream="stderr")
        from selenium.webdriver.common.by import By
        browser.get("http://127.0.0.1:%d/" % port)

        def cell(name: str) -> str:
            cells = browser.find_elements(By.CSS_SELECTOR, "tr[data-node='/crasher'] td.%s" % name)
            return cells[0].text if cells else ""
        until(lambda: cell("restarts") not in ("", "0"), 60, 0.2, what="the crasher restarted in the page")
        for page in range(2):
            states = set()
            for _ in range(6):
                assert cell("exit") == "code 3", (cell("state"), cell("exit"))
                states.add(cell("state"))
                time.sleep(0.3)  # (samples 0.3 s apart)
            assert "running" in states, states
            browser.get("http://127.0.0.1:%d/" % port)  # (a page opened later)
            until(lambda: cell("exit") != "", 30, 0.2, what="the row in a new page")
    finally:
        lp.close()
