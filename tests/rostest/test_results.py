"""Reading a test's JUnit file and judging its run: the rules where rostest is wrong (#935, #2265), without processes."""

from __future__ import annotations

import signal

from lxml import etree

from launcher.rostest.results import TestOutcome, judge, read_result_file, summary, write_junit

GTEST = """<?xml version="1.0" encoding="UTF-8"?>
<testsuites tests="3" failures="0" disabled="0" errors="0" name="AllTests">
  <testsuite name="Sample" tests="3" failures="0" disabled="0" errors="0">
    <testcase name="adds" status="run" classname="Sample"/>
    <testcase name="fails" status="run" classname="Sample"><failure message="one and one are not three">x</failure></testcase>
    <testcase name="crashes" status="run" classname="Sample"><error message="boom"/></testcase>
  </testsuite>
</testsuites>
"""


def test_cases_are_counted_from_testcases_not_the_failures_attribute(tmp_path):
    # the writer says failures="0" (ros_comm#935): the <failure> inside says otherwise
    path = tmp_path / "rosunit-g.xml"
    path.write_text(GTEST)
    cases = read_result_file(str(path), "pkg.rosunit-g")
    assert [(c.name, c.passed) for c in cases] == [("pkg.rosunit-g/adds", True), ("pkg.rosunit-g/fails", False),
                                                  ("pkg.rosunit-g/crashes", False)]
    outcome = judge("g", 1, False, 60, str(path), 1.0, 1)
    assert outcome.problem is None  # gtest exits 1 when a case failed: that is the result, not a problem
    assert (outcome.failures, outcome.errors, outcome.passed) == (1, 1, False)


def test_a_truncated_file_is_read_as_far_as_it_goes(tmp_path):
    path = tmp_path / "r.xml"
    path.write_text(GTEST[:GTEST.index("<testcase name=\"fails\"")])
    assert [c.name.rsplit("/", 1)[1] for c in read_result_file(str(path))] == ["adds"]


def test_run_problems(tmp_path):
    ok = tmp_path / "ok.xml"
    ok.write_text('<testsuite tests="1"><testcase name="a" classname="A"/></testsuite>')
    missing = str(tmp_path / "none.xml")
    assert judge("t", 0, False, 60, str(ok), 1, 1).passed
    # written, then killed by a signal (ros_comm#2265: rostest says SUCCESS)
    assert judge("t", -signal.SIGSEGV, False, 60, str(ok), 1, 1).problem == "test [t] died by signal SIGSEGV"
    assert judge("t", 3, False, 60, str(ok), 1, 1).problem == "test [t] exited with code 3"
    assert judge("t", 0, False, 60, missing, 1, 1).problem == "test [t] did not generate test results"
    assert "timed out after 5 s" in judge("t", -2, True, 5, missing, 5, 1).problem
    empty = tmp_path / "empty.xml"
    empty.write_text('<testsuite tests="0"/>')
    assert "hold no test case" in judge("t", 0, False, 60, str(empty), 1, 1).problem
    assert judge("t", 0, False, 60, missing, 1, 1, text=True).passed  # --text: the exit status decides


def test_summary_never_says_tests_0_for_a_test_that_did_not_run(tmp_path):
    out = summary([TestOutcome("crash", problem="test [crash] died by signal SIGSEGV")])
    assert " * TESTS: 1" in out and "RESULT: FAIL" in out and "testcrash: test [crash] died by signal SIGSEGV" in out


def test_merged_junit(tmp_path):
    src = tmp_path / "g.xml"
    src.write_text(GTEST)
    run = judge("g", 1, False, 60, str(src), 2.0, 1, prefix="pkg.rosunit-g")
    dead = TestOutcome("d", problem="test [d] exited with code 3", time=1.0)
    out = tmp_path / "out" / "rostest-x.xml"
    write_junit(str(out), "rostest", [run, dead])
    suite = etree.parse(str(out)).getroot()
    assert [c.get("name") for c in suite.iter("testcase")] == ["testg", "pkg.rosunit-g/adds", "pkg.rosunit-g/fails",
                                                               "pkg.rosunit-g/crashes", "testd"]
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("5", "2", "1")
