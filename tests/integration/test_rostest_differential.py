"""`launcher test` against Debian's `rostest` on the same test files: same pass/fail per test case, same counts,
same exit status, except where rostest is wrong (a test that segfaults after writing its results)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pytest

from helpers import ROS_PATH
from running import RospyTalker, RosMaster, compile_roscpp, make_package

pytestmark = pytest.mark.integration

ROS_PY = "#!/usr/bin/env python3\n"

PASS_NODE = ROS_PY + '''import unittest
import rospy, rostest
class Passing(unittest.TestCase):
    def test_param(self):
        self.assertEqual(rospy.get_param("/answer"), 42)
    def test_truth(self):
        self.assertTrue(True)
if __name__ == "__main__":
    rospy.init_node("pass_node")
    rostest.rosrun("rttest", "passing", Passing)
'''

FAIL_NODE = ROS_PY + '''import unittest
import rospy, rostest
class Failing(unittest.TestCase):
    def test_good(self):
        self.assertTrue(True)
    def test_bad(self):
        self.assertEqual(1, 2, "one is not two")
    def test_error(self):
        raise RuntimeError("boom")
if __name__ == "__main__":
    rospy.init_node("fail_node")
    rostest.rosrun("rttest", "failing", Failing)
'''

# writes a passing result file as gtest would, then dies by SIGSEGV (a crash in a destructor at exit)
SEGV_NODE = ROS_PY + '''import os, signal, sys
out = [a for a in sys.argv if a.startswith("--gtest_output=xml:")][0].split(":", 1)[1]
with open(out, "w") as f:
    f.write('<?xml version="1.0"?><testsuites tests="1" failures="0" errors="0"><testsuite name="Crash" '
            'tests="1" failures="0" errors="0"><testcase name="works" classname="Crash" status="run"/>'
            '</testsuite></testsuites>')
os.kill(os.getpid(), signal.SIGSEGV)
'''

SLEEP_NODE = ROS_PY + '''import time
time.sleep(600)
'''

# fails on its first run, passes on the next (the count is kept in the file given as the first argument)
FLAKY_NODE = ROS_PY + '''import os, sys, unittest
import rostest
counter = sys.argv[1]
runs = int(open(counter).read()) if os.path.exists(counter) else 0
open(counter, "w").write(str(runs + 1))
class Flaky(unittest.TestCase):
    def test_second_time_lucky(self):
        self.assertGreater(runs, 0, "first run fails")
if __name__ == "__main__":
    rostest.rosrun("rttest", "flaky", Flaky, sysargs=sys.argv)
'''

# the nodes the master knows while the test runs, written to $ROS_HOME/graph.txt (the runners' homes differ)
GRAPH_NODE = ROS_PY + '''import os, unittest
import rosgraph, rospy, rostest
class Graph(unittest.TestCase):
    def test_graph(self):
        pubs, subs, srvs = rosgraph.Master("/graph_node").getSystemState()
        with open(os.path.join(os.environ["ROS_HOME"], "graph.txt"), "w") as f:
            f.write(" ".join(sorted({n for _topic, nodes in pubs + subs + srvs for n in nodes})))
if __name__ == "__main__":
    rospy.init_node("graph_node")
    rostest.rosrun("rttest", "graph", Graph)
'''

# the log file its runner gave it (rospy's init_node puts its own in ROS_LOG_FILENAME: read before it)
LOGFILE_NODE = ROS_PY + '''import os, unittest
AT_START = os.environ.get("ROS_LOG_FILENAME")
import rospy, rostest
class LogFile(unittest.TestCase):
    def test_the_runners_log_file(self):
        self.assertTrue(AT_START and os.path.isfile(AT_START), "ROS_LOG_FILENAME=%r" % AT_START)
if __name__ == "__main__":
    rospy.init_node("logfile_node")
    rostest.rosrun("rttest", "logfile", LogFile)
'''

TALKER = RospyTalker

TESTS = {
    "pass": '<param name="answer" value="42"/>\n<test test-name="passing" pkg="rttest" type="pass_node.py"/>',
    "fail": '<test test-name="failing" pkg="rttest" type="fail_node.py"/>',
    "gtest": '<test test-name="gtest" pkg="rttest" type="gtest_node"/>',
    "timeout": '<test test-name="sleeper" pkg="rttest" type="sleep_node.py" time-limit="3"/>',
    "segv": '<test test-name="crash" pkg="rttest" type="segv_node.py"/>',
    "retry": '<test test-name="flaky" pkg="rttest" type="flaky_node.py" retry="2" args="{counter}"/>',
    "hz": ('<node name="talker" pkg="rttest" type="talker.py"/>\n'
           '<test test-name="hztest" pkg="rostest" type="hztest" name="hz">\n'
           '  <param name="topic" value="chatter"/><param name="hz" value="20.0"/>\n'
           '  <param name="hzerror" value="5.0"/><param name="test_duration" value="2.0"/>\n</test>'),
    "param": ('<param name="robot/speed" value="3"/>\n'
              '<test test-name="paramtest" pkg="rostest" type="paramtest" name="pt">\n'
              '  <param name="param_name_target" value="/robot/speed"/>\n'
              '  <param name="param_value_expected" value="3"/><param name="test_duration" value="1.0"/>\n</test>'),
    "advertise": ('<node name="talker" pkg="rttest" type="talker.py"/>\n'
                  '<test test-name="advertisetest" pkg="rostest" type="advertisetest" name="adv">\n'
                  '  <rosparam>\n    topics:\n      - name: /chatter\n        timeout: 10\n'
                  '        type: std_msgs/String\n      - name: /nobody\n        timeout: 1\n        negative: true\n'
                  '  </rosparam>\n</test>'),
    "clean": '<param name="fresh" value="1"/>\n<test test-name="clean" pkg="rttest" type="clean_node.py"/>',
    "missing": '<test test-name="ghost" pkg="rttest" type="no_such_test.py"/>',
    "badfixture": ('<node name="ghost" pkg="rttest" type="no_such_node.py"/>\n'
                   '<test test-name="passing" pkg="rttest" type="pass_node.py"/>'),
    "numbered": ('<param name="answer" value="42"/>\n<node name="talker" pkg="rttest" type="talker.py"/>\n'
                 '<test test-name="first" pkg="rttest" type="pass_node.py" name="one"/>\n'
                 '<test test-name="second" pkg="rttest" type="pass_node.py" name="two" ns="sub"/>'),
    "unparsable": '<test test-name="broken" pkg="rttest"\n',
    "graph": '<test test-name="graph" pkg="rttest" type="graph_node.py"/>',
    "logfile": '<test test-name="logfile" pkg="rttest" type="logfile_node.py"/>',
    "publish": ('<node name="talker" pkg="rttest" type="talker.py"/>\n'
                '<test test-name="publishtest" pkg="rostest" type="publishtest" name="pub">\n'
                '  <rosparam>\n    topics:\n      - name: chatter\n        timeout: 10\n  </rosparam>\n</test>'),
}


@pytest.fixture(scope="module")
def workspace(tmp_path_factory, ros_env):
    root = str(tmp_path_factory.mktemp("rostest"))
    src = os.path.join(root, "src")
    pkg = make_package(src, "rttest", {"pass_node.py": PASS_NODE, "fail_node.py": FAIL_NODE,
                                       "segv_node.py": SEGV_NODE, "sleep_node.py": SLEEP_NODE,
                                       "flaky_node.py": FLAKY_NODE, "talker.py": TALKER,
                                       "clean_node.py": NO_STALE_NODE, "graph_node.py": GRAPH_NODE,
                                       "logfile_node.py": LOGFILE_NODE})
    try:
        compile_roscpp("gtest_node.cpp", os.path.join(pkg, "gtest_node"), libs=("-lgtest", "-lpthread"))
    except subprocess.CalledProcessError:
        pytest.fail("cannot compile the gtest node (libgtest-dev installed?)")
    for name, body in TESTS.items():
        with open(os.path.join(pkg, name + ".test"), "w") as f:
            f.write('<launch>\n%s\n</launch>\n' % body)
    return root, pkg


def _env(root: str, who: str) -> dict[str, str]:
    env = dict(os.environ)
    # Debian's python first: the test nodes' `#!/usr/bin/env python3` must find rospy
    env.update(PATH=ROS_PATH + ":" + env.get("PATH", ""), ROS_HOME=os.path.join(root, who, "home"),
               ROS_LOG_DIR=os.path.join(root, who, "log"),
               ROS_PACKAGE_PATH=os.path.join(root, "src") + ":/usr/share", ROS_IP="127.0.0.1")
    for k in ("ROS_MASTER_URI", "ROS_NAMESPACE", "ROS_HOSTNAME", "ROS_TEST_RESULTS_DIR"):
        env.pop(k, None)
    return env


def _test_file(pkg: str, name: str, who: str) -> str:
    """The test file as `who` runs it (retry's counter is per runner)."""
    path = os.path.join(pkg, name + ".test")
    if name != "retry":
        return path
    counter = os.path.join(os.path.dirname(pkg), "..", "flaky-%s-%d" % (who, time.monotonic_ns()))
    mine = os.path.join(pkg, "retry_%s.test" % who)
    with open(mine, "w") as f:
        f.write('<launch>\n%s\n</launch>\n' % TESTS["retry"].format(counter=os.path.abspath(counter)))
    return mine


NO_STALE_NODE = ROS_PY + '''import unittest
import rospy, rostest
class Clean(unittest.TestCase):
    def test_no_stale_param(self):
        self.assertFalse(rospy.has_param("/stale"), "a parameter of an earlier run is still set")
    def test_own_param(self):
        self.assertEqual(rospy.get_param("/fresh"), 1)
if __name__ == "__main__":
    rospy.init_node("clean_node")
    rostest.rosrun("rttest", "clean", Clean)
'''


class Summary:
    def __init__(self, proc: subprocess.CompletedProcess):
        self.rc = proc.returncode
        self.out = proc.stdout + proc.stderr
        text = re.sub(r"\x1b\[[0-9;]*m", "", proc.stdout)
        self.cases = {m.group(1): m.group(2) for m in re.finditer(r"^\[([^\]]+/[^\]]+)\]\[(passed|FAILURE|ERROR)\]",
                                                                    text, re.M)}
        self.failed_runs = re.findall(r"^\[(test[^\]]+)\]\[failed\]", text, re.M)
        counts = {k: int(v) for k, v in re.findall(r"^ \* (TESTS|ERRORS|FAILURES): (\d+)", text, re.M)}
        self.tests, self.errors, self.failures = counts.get("TESTS"), counts.get("ERRORS"), counts.get("FAILURES")
        self.success = "RESULT: SUCCESS" in text

    def __repr__(self) -> str:
        return "rc=%s cases=%s failed_runs=%s\n%s" % (self.rc, self.cases, self.failed_runs, self.out[-3000:])


def rostest(root: str, pkg: str, name: str) -> Summary:
    proc = subprocess.run(["rostest", "rttest", os.path.basename(_test_file(pkg, name, "rostest"))],
                          env=_env(root, "rostest"), capture_output=True, text=True, timeout=180)
    return Summary(proc)


def ours(root: str, pkg: str, name: str, *extra: str) -> Summary:
    proc = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "test", *extra, "rttest",
                           os.path.basename(_test_file(pkg, name, "ours"))],
                          env=_env(root, "ours"), capture_output=True, text=True, timeout=180)
    return Summary(proc)


@pytest.mark.parametrize("name, rc", [("pass", 0), ("fail", 2), ("gtest", 2), ("retry", 0), ("hz", 0),
                                      ("param", 0), ("publish", 0),
                                      ("advertise", 0), ("logfile", 0)])
def test_same_results_as_rostest(workspace, name, rc):
    root, pkg = workspace
    theirs, mine = rostest(root, pkg, name), ours(root, pkg, name)
    assert theirs.rc == rc, theirs
    assert mine.rc == rc, mine
    assert mine.cases == theirs.cases, (mine, theirs)
    assert (mine.tests, mine.errors, mine.failures) == (theirs.tests, theirs.errors, theirs.failures), (mine, theirs)
    assert mine.cases and mine.success == (rc == 0)


def test_failing_cases_are_named(workspace):
    root, pkg = workspace
    mine = ours(root, pkg, "fail")
    assert mine.cases == {"rttest.rosunit-failing/test_good": "passed", "rttest.rosunit-failing/test_bad": "FAILURE",
                          "rttest.rosunit-failing/test_error": "ERROR"}, mine
    assert "one is not two" in mine.out


def test_timeout_fails_like_rostest_with_the_reason(workspace):
    root, pkg = workspace
    theirs, mine = rostest(root, pkg, "timeout"), ours(root, pkg, "timeout")
    # rostest counts the timed-out test as a runner error ("TESTS: 0, ERRORS: 1"); we say which test failed and why
    assert theirs.rc == 1 and theirs.errors == 1 and "max time [3.0s]" in theirs.out, theirs
    assert mine.rc == 1 and mine.failed_runs == ["testsleeper"] and mine.failures == 1, mine
    assert "timed out after 3 s" in mine.out


def test_segfault_after_results_is_a_failure_where_rostest_says_success(workspace):
    root, pkg = workspace
    theirs, mine = rostest(root, pkg, "segv"), ours(root, pkg, "segv")
    # rostest is wrong here (ros_comm#2265): it trusts the result file and ignores the SIGSEGV
    assert theirs.rc == 0 and theirs.success, theirs
    assert mine.rc == 1 and not mine.success, mine
    assert mine.failed_runs == ["testcrash"] and "died by signal SIGSEGV" in mine.out, mine
    assert mine.cases == theirs.cases == {"rttest.rosunit-crash/works": "passed"}


def test_junit_results_merge_each_tests_cases(workspace):
    from lxml import etree
    root, pkg = workspace
    out = os.path.join(root, "merged.xml")
    mine = ours(root, pkg, "fail", "--junit-xml", out)
    assert mine.rc == 2, mine
    suite = etree.parse(out).getroot()
    names = [c.get("name") for c in suite.iter("testcase")]
    assert names == ["testfailing", "rttest.rosunit-failing/test_bad", "rttest.rosunit-failing/test_error",
                     "rttest.rosunit-failing/test_good"], names
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("4", "1", "1")
    # rostest's own place for it is untouched by --junit-xml, and the test's own file is where rostest keeps it
    assert os.path.isfile(os.path.join(root, "ours", "home", "test_results", "rttest", "rosunit-failing.xml"))


def test_default_results_file_is_rostests(workspace):
    root, pkg = workspace
    mine = ours(root, pkg, "pass")
    assert mine.rc == 0, mine
    path = os.path.join(root, "ours", "home", "test_results", "rttest", "rostest-pass.xml")
    with open(path) as f:
        text = f.read()
    assert 'name="testpassing"' in text and 'rttest.rosunit-passing/test_param' in text


def test_two_runs_of_one_file_in_parallel_do_not_interfere(workspace):
    root, pkg = workspace
    env = _env(root, "parallel")
    procs = [subprocess.Popen([sys.executable, "-m", "launcher.cli.tool", "test", "--results-filename", "p%d.xml" % i,
                               "rttest", "param.test"], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True) for i in range(2)]
    outs = [p.communicate(timeout=180)[0] for p in procs]
    for p, out in zip(procs, outs):
        assert p.returncode == 0, out
        assert "RESULT: SUCCESS" in out
    uris = [re.search(r"ROS_MASTER_URI=(\S+)", out).group(1) for out in outs]
    assert uris[0] != uris[1]


@pytest.mark.parametrize("clear", [False, True])
def test_reuse_master_and_clear_like_rostest(workspace, tmp_path, clear):
    root, pkg = workspace
    master = RosMaster(str(tmp_path))
    try:
        results = {}
        for who, argv in (("rostest", ["rostest"]), ("ours", [sys.executable, "-m", "launcher.cli.tool", "test"])):
            env = _env(root, who)
            env["ROS_MASTER_URI"] = "http://127.0.0.1:%d/" % master.port
            # (rostest insists on a /run_id, as roscore sets it)
            subprocess.run(["rosparam", "set", "/run_id", "reused"], env=env, check=True, timeout=60)
            subprocess.run(["rosparam", "set", "/stale", "1"], env=env, check=True, timeout=60)
            extra = ["--reuse-master"] + (["--clear"] if clear else [])
            proc = subprocess.run(argv + extra + ["rttest", "clean.test"], env=env, capture_output=True, text=True,
                                  timeout=180)
            results[who] = Summary(proc)
        theirs, mine = results["rostest"], results["ours"]
        assert theirs.rc == (0 if clear else 2), theirs
        assert mine.rc == theirs.rc, mine
        assert mine.cases == theirs.cases, (mine, theirs)
        # the master outlives the runs (it was not ours to stop)
        assert master.proc.poll() is None
    finally:
        master.stop()


def test_missing_test_executable_and_broken_fixture(workspace):
    root, pkg = workspace
    for name, words in (("missing", "Test node [rttest/no_such_test.py] does not exist"),
                        ("badfixture", "Test Fixture Nodes ['/ghost'] failed to launch")):
        theirs, mine = rostest(root, pkg, name), ours(root, pkg, name)
        assert theirs.rc == 1 and not theirs.success, theirs
        assert mine.rc == 1 and not mine.success and words in mine.out, mine
        assert len(mine.failed_runs) == 1


def test_text_mode_shows_the_test_output_and_passes_on_exit_status(workspace):
    root, pkg = workspace
    mine = ours(root, pkg, "pass", "--text")
    assert mine.rc == 0, mine
    assert "test_param" in mine.out  # the unittest's own report, on the screen


def test_processes_are_numbered_as_rostest_numbers_them(workspace, tmp_path):
    """One counter for the whole file, fixture nodes first, no rosout process: the log files' names."""
    root, pkg = workspace
    names = {}
    for who, argv in (("rostest", ["rostest"]), ("ours", [sys.executable, "-m", "launcher.cli.tool", "test"])):
        env = _env(root, who)
        env["ROS_LOG_DIR"] = str(tmp_path / who)
        proc = subprocess.run(argv + ["rttest", "numbered.test"], env=env, capture_output=True, text=True,
                              timeout=180)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        names[who] = sorted(f for _dir, _subdirs, files in os.walk(tmp_path / who) for f in files
                            if f.endswith("-stdout.log"))
    assert names["rostest"] == ["one-2-stdout.log", "sub-two-4-stdout.log", "talker-1-stdout.log",
                                "talker-3-stdout.log"], names
    assert names["ours"] == names["rostest"]


def test_the_same_graph_as_rostest_no_rosout(workspace):
    """rostest's master runs inside it and is up before its runner launches, so roslaunch's core nodes
    (rosout) are never started: the test sees only its own nodes (no rosout, and no /diagnostics publisher of
    ours), and no rosout or master lines are printed."""
    root, pkg = workspace
    graphs = {}
    for who, run in (("rostest", rostest), ("ours", ours)):
        result = run(root, pkg, "graph")
        assert result.rc == 0, result
        with open(os.path.join(root, who, "home", "graph.txt")) as f:
            graphs[who] = f.read()
        assert "[rosout-1]" not in result.out and "[master] killing" not in result.out, result
    assert graphs["rostest"] == "/graph"  # (the test's name: `name` defaults to test-name)
    assert graphs["ours"] == graphs["rostest"]


@pytest.mark.parametrize("name, words", [("nothere", "rostest file [%s] does not exist"),
                                         ("unparsable", "rostest file [%s] does not load: ")])
def test_a_test_file_that_cannot_run_is_a_failed_result(workspace, name, words):
    """rostest is wrong here: it means to write a failed `test_ran` result for a test file that does not exist
    (rostest_main.write_bad_filename_failure, #1140), but exits before it gets there (resolving the arguments
    fails first; a file that does not parse ends in a traceback), so a CI job that reads the results sees
    nothing, or an earlier run's success. Both exit 1; we write the result it meant, in its layout."""
    from lxml import etree
    root, pkg = workspace
    path = os.path.join(pkg, name + ".test")
    for who, argv in (("rostest", ["rostest"]), ("ours", [sys.executable, "-m", "launcher.cli.tool", "test"])):
        env = _env(root, who)
        results = os.path.join(root, who, "home", "test_results", "rttest", "rostest-%s.xml" % name)
        os.makedirs(os.path.dirname(results), exist_ok=True)
        with open(results, "w") as f:  # an earlier run's, when the file was fine
            f.write('<?xml version="1.0"?><testsuite tests="1" failures="0" errors="0" name="%s">'
                    '<testcase name="testok" classname="rostest.runner.RosTest"/></testsuite>' % name)
        proc = subprocess.run(argv + ["rttest", name + ".test"], env=env, capture_output=True, text=True,
                              timeout=180)
        assert proc.returncode == 1, (who, proc.stdout + proc.stderr)
        suite = etree.parse(results).getroot()
        if who == "rostest":
            assert suite.get("failures") == "0", "rostest now writes its failure result: match it"
            continue
        assert "Generated failure case result file in %s" % results in proc.stderr, proc.stderr
        assert (suite.get("name"), suite.get("tests"), suite.get("failures"), suite.get("errors")) == \
            (name, "1", "1", "0")
        case, = suite.iter("testcase")
        assert (case.get("name"), case.get("classname")) == ("test_ran", "Results")
        assert case.find("failure").get("message").startswith(words % path), etree.tostring(suite)


def test_no_failure_result_for_a_command_line_that_names_no_package(workspace):
    root, pkg = workspace
    env = _env(root, "nopkg")
    proc = subprocess.run([sys.executable, "-m", "launcher.cli.tool", "test", "no_such_pkg", "x.test"], env=env,
                          cwd=pkg, capture_output=True, text=True, timeout=180)  # (cwd: inside a package)
    assert proc.returncode == 1 and "is neither a launch file in package [no_such_pkg]" in proc.stderr, proc.stderr
    assert not os.path.exists(os.path.join(root, "nopkg", "home", "test_results")), proc.stderr
