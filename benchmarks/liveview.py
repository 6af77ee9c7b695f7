#!/usr/bin/env python3
"""The live view's cost: the launcher's CPU on a launch of N idle nodes with no view, with the terminal view
attached, and with one page connected; the bytes a page receives while nothing changes; the view library's import.

    python3 benchmarks/liveview.py [--n 500] [--seconds 30] [--cmd 'python3 -m launcher']

One launch of N sleepers (benchmarks/monitor.py's, sampled every second:
the resource sampling is counted on every side), measured three ways in a
row, each over `--seconds`: alone; with `launcher ui` running in a real
terminal (tmux, 80x24); with `launcher web` serving one page whose event
stream a raw client reads (the bytes it gets are counted; a browser would get
the same stream). The launcher's CPU is read from /proc (all threads); the
view's own process is reported beside it. Goals (issue 22): each view <= 3 %
of a core above the launch alone, the page <= 5 kB/s.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from monitor import cpu_seconds, free_port, make_launch  # noqa: E402  (the same launch as the monitor's benchmark)
from common import tool_command  # noqa: E402


def window(pids: list[int], seconds: float) -> list[float]:
    """Each process's CPU over the window, in percent of one core."""
    before, t0 = [cpu_seconds(p) for p in pids], time.monotonic()
    time.sleep(seconds)
    after, t1 = [cpu_seconds(p) for p in pids], time.monotonic()
    return [100.0 * (a - b) / (t1 - t0) for a, b in zip(after, before)]


def import_cost(python: str, reps: int = 5) -> float:
    code = ("import time; t = time.perf_counter(); import prompt_toolkit.application, prompt_toolkit.layout, "
            "prompt_toolkit.key_binding; print(time.perf_counter() - t)")
    return statistics.median(float(subprocess.check_output([python, "-c", code])) for _ in range(reps))


def browser_window(launch_pid: int, web_pid: int, port: int, args: argparse.Namespace, alone: float) -> None:
    """The same with Debian's headless Chromium showing the page (its own CPU is not the launcher's)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    try:
        driver.get("http://127.0.0.1:%d/" % port)
        deadline = time.monotonic() + 60
        while len(driver.find_elements("css selector", "#nodes tbody tr")) < args.n:
            if time.monotonic() > deadline:
                raise SystemExit("the page did not show the %d nodes" % args.n)
            time.sleep(0.5)
        time.sleep(3)
        with_browser, web_own = window([launch_pid, web_pid], args.seconds)
        print("%d idle nodes, Chromium on the page: launcher %.2f %% (+%.2f), the page server %.2f %%"
              % (args.n, with_browser, with_browser - alone, web_own))
    finally:
        driver.quit()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--seconds", type=float, default=30)
    ap.add_argument("--cmd", default="%s -m launcher" % sys.executable)
    args = ap.parse_args()
    cmd = shlex.split(args.cmd)
    tool = tool_command(cmd)
    print("prompt_toolkit import: %.0f ms (median of 5, a fresh interpreter each)" % (1e3 * import_cost(cmd[0])))
    with tempfile.TemporaryDirectory(prefix="liveview-bench-") as root:
        launch = make_launch(root, args.n)
        env = dict(os.environ, ROS_PACKAGE_PATH=root, ROS_HOME=os.path.join(root, "home"),
                   ROS_LOG_DIR=os.path.join(root, "log"), ROS_MASTER_URI="http://127.0.0.1:%d/" % free_port(),
                   ROS_IP="127.0.0.1")
        out = open(os.path.join(root, "out.txt"), "w+")
        p = subprocess.Popen(cmd + [launch, "--no-summary", "--skip-log-check", "--monitor-period", "1"], env=env,
                             stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        tmux = ["tmux", "-L", "liveview-bench-%d" % os.getpid()]
        try:
            deadline = time.monotonic() + 180
            while len(re.findall(r"started with pid", open(out.name).read())) < args.n:
                if p.poll() is not None or time.monotonic() > deadline:
                    raise SystemExit("the launch did not start %d nodes" % args.n)
                time.sleep(0.5)
            time.sleep(5)  # (start-up's own work is not measured)
            alone = window([p.pid], args.seconds)[0]
            print("%d idle nodes, no view:           launcher %.2f %% of a core" % (args.n, alone))

            command = "env %s %s ui" % (" ".join(shlex.quote("%s=%s" % kv) for kv in env.items()),
                                        " ".join(shlex.quote(a) for a in tool))
            subprocess.run(tmux + ["new-session", "-d", "-s", "b", "-x", "80", "-y", "24", command], check=True)
            view_pid = None
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                shown = subprocess.run(tmux + ["capture-pane", "-p", "-t", "b"], capture_output=True, text=True).stdout
                if "running" in shown:
                    view_pid = int(subprocess.check_output(tmux + ["display-message", "-p", "-t", "b", "#{pane_pid}"]))
                    break
                time.sleep(0.5)
            if view_pid is None:
                raise SystemExit("the terminal view did not show the launch")
            time.sleep(3)
            with_ui, ui_own = window([p.pid, view_pid], args.seconds)
            print("%d idle nodes, terminal view open: launcher %.2f %% (+%.2f), the view's process %.2f %%"
                  % (args.n, with_ui, with_ui - alone, ui_own))
            subprocess.run(tmux + ["kill-server"], capture_output=True)

            port = free_port()
            web = subprocess.Popen(tool + ["web", str(port)], env=env, stderr=subprocess.PIPE)
            web.stderr.readline()  # "the live view of ... at ..."
            received = [0]
            first = threading.Event()
            conn = socket.create_connection(("127.0.0.1", port))
            conn.sendall(b"GET /events HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n\r\n" % port)

            def read() -> None:
                while True:
                    try:
                        data = conn.recv(65536)
                    except OSError:
                        return
                    if not data:
                        return
                    if first.is_set():
                        received[0] += len(data)
                    elif b"snapshot" in data:
                        first.set()
            threading.Thread(target=read, daemon=True).start()
            first.wait(30)
            time.sleep(5)  # (the snapshot's tail and the first samples are not what is measured)
            received[0] = 0
            with_web, web_own = window([p.pid, web.pid], args.seconds)
            rate = received[0] / args.seconds
            print("%d idle nodes, one page connected: launcher %.2f %% (+%.2f), the page server %.2f %%, the page "
                  "receives %.1f B/s (%d bytes in %g s)" % (args.n, with_web, with_web - alone, web_own, rate, received[0],
                                                        args.seconds))
            conn.close()
            if os.path.exists("/usr/bin/chromium") and os.path.exists("/usr/bin/chromedriver"):
                browser_window(p.pid, web.pid, port, args, alone)
            web.send_signal(signal.SIGINT)
            web.wait(10)
        finally:
            subprocess.run(tmux + ["kill-server"], capture_output=True)
            p.send_signal(signal.SIGINT)
            try:
                p.wait(120)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
            out.close()


if __name__ == "__main__":
    main()
