#!/usr/bin/env python3
"""`launcher test` against Debian's `rostest` on the same test file: wall time, paired (ABBA), with the exit statuses.

    python3 benchmarks/rostest_wall.py [--reps 5] [--file pass|param|gtest ...]

Run it with the Python launcher is installed for (`launcher test` needs lxml); the
tools' own PATH (Debian's rostest and python first) is set here.

Builds a scratch package with a passing rospy unittest node (two cases, one reads a
parameter), a paramtest file and a hztest file; each repetition runs both tools in
ABBA order so that the ratio compares neighbours on a shared, noisy machine.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

from common import ROS_PATH  # (this folder is on the path of a script run from it)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE_XML = ('<?xml version="1.0"?>\n<package format="2"><name>benchtest</name><version>0.0.1</version>'
               '<description>d</description><maintainer email="m@example.com">m</maintainer>'
               '<license>BSD</license></package>\n')
PASS_NODE = '''#!/usr/bin/env python3
import unittest
import rospy, rostest
class Passing(unittest.TestCase):
    def test_param(self):
        self.assertEqual(rospy.get_param("/answer"), 42)
    def test_truth(self):
        self.assertTrue(True)
if __name__ == "__main__":
    rospy.init_node("pass_node")
    rostest.rosrun("benchtest", "passing", Passing)
'''
TESTS = {
    "pass": '<param name="answer" value="42"/><test test-name="passing" pkg="benchtest" type="pass_node.py"/>',
    "param": ('<param name="speed" value="3"/><test test-name="paramtest" pkg="rostest" type="paramtest" name="pt">'
              '<param name="param_name_target" value="/speed"/><param name="param_value_expected" value="3"/>'
              '<param name="test_duration" value="0.5"/></test>'),
    "two": ('<param name="answer" value="42"/><test test-name="first" pkg="benchtest" type="pass_node.py"/>'
            '<test test-name="second" pkg="benchtest" type="pass_node.py"/>'),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--file", action="append", choices=sorted(TESTS), help="test files to time (default: all)")
    opts = ap.parse_args()
    if shutil.which("rostest", path=ROS_PATH) is None:
        print("rostest is not installed (python3-rostest)", file=sys.stderr)
        return 1
    tmp = tempfile.mkdtemp(prefix="bench-rostest-")
    try:
        pkg = os.path.join(tmp, "src", "benchtest")
        os.makedirs(pkg)
        with open(os.path.join(pkg, "package.xml"), "w") as f:
            f.write(PACKAGE_XML)
        node = os.path.join(pkg, "pass_node.py")
        with open(node, "w") as f:
            f.write(PASS_NODE)
        os.chmod(node, 0o755)
        for name, body in TESTS.items():
            with open(os.path.join(pkg, name + ".test"), "w") as f:
                f.write("<launch>%s</launch>\n" % body)
        env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_")}
        env.update(PATH=ROS_PATH + ":" + env.get("PATH", ""), ROS_PACKAGE_PATH=os.path.join(tmp, "src"),
                   ROS_HOME=os.path.join(tmp, "home"), ROS_IP="127.0.0.1",
                   PYTHONPATH=ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else ""))
        cmds = {"rostest": ["rostest"], "launcher": [sys.executable, "-m", "launcher.cli.tool", "test"]}
        for name in opts.file or sorted(TESTS):
            times: dict[str, list[float]] = {"rostest": [], "launcher": []}
            codes: dict[str, set[int]] = {"rostest": set(), "launcher": set()}
            ratios = []
            for rep in range(opts.reps):
                order = ["rostest", "launcher"] if rep % 2 == 0 else ["launcher", "rostest"]
                pair = {}
                for who in order:
                    t0 = time.monotonic()
                    p = subprocess.run(cmds[who] + ["benchtest", name + ".test"], env=env, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.DEVNULL, timeout=300)
                    pair[who] = time.monotonic() - t0
                    codes[who].add(p.returncode)
                    times[who].append(pair[who])
                ratios.append(pair["launcher"] / pair["rostest"])
            print("%-6s rostest %.2f s (exit %s)  launcher test %.2f s (exit %s)  ratio %.2f  [medians of %d, ABBA]"
                  % (name, statistics.median(times["rostest"]), sorted(codes["rostest"]),
                     statistics.median(times["launcher"]), sorted(codes["launcher"]), statistics.median(ratios),
                     opts.reps))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
