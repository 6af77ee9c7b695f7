#!/usr/bin/env python3
"""README's pictures of the live view, made from a real launch: `launch --ui --web PORT` on a few rospy nodes in
tmux (80x24); the terminal as tmux holds it (capture-pane -e) drawn by headless Chromium, and the page itself.

    python3 docs/screenshots.py     (needs Debian's rospy, tmux, chromium, chromium-driver, and selenium)

Writes docs/images/ui.png and docs/images/web.png.
"""

from __future__ import annotations

import html
import os
import re
import shlex
import socket
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
IMAGES = os.path.join(HERE, "images")
NODE = """#!/usr/bin/python3
import rospy, random
from std_msgs.msg import String
rospy.init_node("%s")
pub = rospy.Publisher("chatter", String, queue_size=1)
rospy.Subscriber("chatter", String, lambda m: None)
n = 0
while not rospy.is_shutdown():
    n += 1
    if n %% 7 == 0:
        rospy.logwarn("tick %%d: a warning", n)
    else:
        rospy.loginfo("tick %%d", n)
    pub.publish(String("hi"))
    rospy.sleep(0.7 + random.random())
"""
COLORS = ["#000", "#c33", "#3a3", "#cc3", "#36c", "#c3c", "#3cc", "#ccc"]
BRIGHT = ["#777", "#f66", "#6f6", "#ff6", "#69f", "#f6f", "#6ff", "#fff"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ansi_to_html(text: str) -> str:
    """tmux's capture-pane -e (SGR colours, bold, reverse) as HTML spans."""
    out, fg, bg, bold, rev = [], None, None, False, False
    for part in re.split(r"(\x1b\[[0-9;]*m)", text):
        if part.startswith("\x1b["):
            codes = [int(c) for c in part[2:-1].split(";") if c] or [0]
            i = 0
            while i < len(codes):
                c = codes[i]
                if c == 0:
                    fg = bg = None
                    bold = rev = False
                elif c == 1:
                    bold = True
                elif c == 22:
                    bold = False
                elif c == 7:
                    rev = True
                elif c == 27:
                    rev = False
                elif 30 <= c <= 37:
                    fg = COLORS[c - 30]
                elif 90 <= c <= 97:
                    fg = BRIGHT[c - 90]
                elif c == 39:
                    fg = None
                elif 40 <= c <= 47:
                    bg = COLORS[c - 40]
                elif c == 49:
                    bg = None
                elif c in (38, 48) and i + 2 < len(codes) and codes[i + 1] == 5:
                    i += 2  # (256 colours: drawn as the default)
                i += 1
            continue
        f, b = (bg or "#111", fg or "#ddd") if rev else (fg or "#ddd", bg)
        style = "color:%s;%s%s" % (f, "background:%s;" % b if b else "", "font-weight:bold;" if bold else "")
        out.append('<span style="%s">%s</span>' % (style, html.escape(part)))
    return ("<html><body style='margin:0;background:#111'><pre style='font:14px/1.25 monospace;margin:8px;"
            "color:#ddd'>%s</pre></body></html>" % "".join(out))


def main() -> None:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    os.makedirs(IMAGES, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="screenshots-") as root:
        pkg = os.path.join(root, "pkgs", "demo_view")
        os.makedirs(pkg)
        with open(os.path.join(pkg, "package.xml"), "w") as f:
            f.write("<package><name>demo_view</name><version>0.0.0</version></package>")
        names = ["camera_driver", "lidar_driver", "odometry", "planner", "controller", "teleop"]
        for name in names:
            path = os.path.join(pkg, name)
            with open(path, "w") as f:
                f.write(NODE % name)
            os.chmod(path, 0o755)
        launch = os.path.join(root, "robot.launch")
        with open(launch, "w") as f:
            f.write("<launch>\n%s</launch>\n" % "".join(
                '  <node pkg="demo_view" type="%s" name="%s"%s/>\n' % (n, n, ' output="screen"' if i % 2 else "")
                for i, n in enumerate(names)))
        port = free_port()
        env = dict(os.environ, ROS_PACKAGE_PATH=os.path.join(root, "pkgs"), ROS_HOME=os.path.join(root, "home"),
                   ROS_LOG_DIR=os.path.join(root, "log"), ROS_MASTER_URI="http://127.0.0.1:%d/" % free_port(),
                   ROS_IP="127.0.0.1", TERM="xterm-256color")
        tmux = ["tmux", "-L", "screenshots-%d" % os.getpid()]
        command = "env %s %s -m launcher --ui --web %d %s" % (
            " ".join(shlex.quote("%s=%s" % kv) for kv in env.items()), sys.executable, port, launch)
        subprocess.run(tmux + ["new-session", "-d", "-s", "s", "-x", "80", "-y", "24", command], check=True)
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1200,700"):
            options.add_argument(arg)
        driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
        try:
            deadline = time.monotonic() + 60
            while subprocess.run(tmux + ["capture-pane", "-p", "-t", "s"], capture_output=True, text=True
                                 ).stdout.count("running") < len(names) + 0:
                if time.monotonic() > deadline:
                    raise SystemExit("the view did not show every node running")
                time.sleep(0.5)
            subprocess.run(tmux + ["send-keys", "-t", "s", "j", "j"], check=True)
            time.sleep(12)  # (uptimes, samples and output to show)
            screen = subprocess.run(tmux + ["capture-pane", "-p", "-e", "-t", "s"], capture_output=True,
                                    text=True).stdout
            page = os.path.join(root, "ui.html")
            with open(page, "w") as f:
                f.write(ansi_to_html(screen))
            driver.set_window_size(780, 640)
            driver.get("file://" + page)
            driver.save_screenshot(os.path.join(IMAGES, "ui.png"))
            driver.set_window_size(1200, 640)
            driver.get("http://127.0.0.1:%d/" % port)
            time.sleep(20)  # (the sparklines fill)
            driver.save_screenshot(os.path.join(IMAGES, "web.png"))
        finally:
            driver.quit()
            subprocess.run(tmux + ["send-keys", "-t", "s", "q"])
            time.sleep(5)
            subprocess.run(tmux + ["kill-server"], capture_output=True)
    print("wrote %s and %s" % (os.path.join(IMAGES, "ui.png"), os.path.join(IMAGES, "web.png")))


if __name__ == "__main__":
    main()
