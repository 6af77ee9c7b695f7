"""Test results: reading a test node's JUnit file, judging a test run, and writing rostest's JUnit layout.

A test passes only when its process exited 0 *and* the result file it wrote
holds at least one test case and no failure or error. rostest trusts the file
alone (a test that wrote its results and then segfaulted passes, ros_comm#2265)
and the file's `failures=` attribute (which some writers leave at 0, #935):
here the test cases themselves are counted.
"""

from __future__ import annotations

import os
from typing import NamedTuple

from lxml import etree

from launcher.compat import removeprefix

# rosunit's rule (#576) for a test name inside a file name
_FILENAME_UNSAFE = ' "\'&$!`/\\'


class CaseResult(NamedTuple):
    """One test case: `name` as rosunit prints it (`<dir>.<file>/<case>`), and what went wrong, if anything."""

    name: str
    classname: str
    time: float = 0.0
    failures: tuple[str, ...] = ()
    errors: tuple[str, ...] = ()
    skipped: bool = False

    @property
    def passed(self) -> bool:
        return not self.failures and not self.errors


class TestOutcome(NamedTuple):
    """One `<test>`'s final attempt: its cases (from its result file) and why the run itself failed, if it did."""

    __test__ = False  # (not a pytest test class, whatever its name)

    test_name: str
    cases: tuple[CaseResult, ...] = ()
    problem: str | None = None  # "exited with code 3", "died by signal SIGSEGV", "timed out after 60 s", ...
    time: float = 0.0
    attempts: int = 1
    result_file: str | None = None

    @property
    def failures(self) -> int:
        return sum(1 for c in self.cases if c.failures)

    @property
    def errors(self) -> int:
        return sum(1 for c in self.cases if c.errors and not c.failures)

    @property
    def passed(self) -> bool:
        return self.problem is None and self.failures == 0 and self.errors == 0


def safe_test_name(name: str) -> str:
    for c in _FILENAME_UNSAFE:
        name = name.replace(c, "_")
    return name


def results_dir(environ: dict[str, str], base_dir: str | None = None) -> str:
    """rospkg's test results directory: `--results-base-dir`, ROS_TEST_RESULTS_DIR, else $ROS_HOME/test_results."""
    if base_dir:
        return base_dir
    if environ.get("ROS_TEST_RESULTS_DIR"):
        return environ["ROS_TEST_RESULTS_DIR"]
    from launcher.workspace.roshome import ros_home
    return os.path.join(ros_home(environ), "test_results")


def _text(el: etree._Element) -> str:
    parts = [el.get("message") or ""]
    if el.text and el.text.strip():
        parts.append(el.text.strip())
    return "\n".join(p for p in parts if p) or el.tag


def read_result_file(path: str, prefix: str | None = None) -> tuple[CaseResult, ...]:
    """The test cases of a JUnit file (gtest's, rosunit's, pytest's ...). ValueError if it cannot be read.

    Nested suites are flattened (as rosunit reads them); a truncated file (its writer crashed) is read
    as far as it goes.
    """
    try:
        tree = etree.parse(path, etree.XMLParser(recover=True, huge_tree=True))
    except (OSError, etree.XMLSyntaxError) as e:
        raise ValueError("cannot read test results [%s]: %s" % (path, e)) from None
    root = tree.getroot()
    if root is None or root.tag not in ("testsuite", "testsuites"):
        raise ValueError("test results [%s] hold no <testsuite>" % path)
    prefix = prefix or "%s.%s" % (os.path.basename(os.path.dirname(os.path.abspath(path))),
                        removeprefix(os.path.splitext(os.path.basename(path))[0], "TEST-"))
    cases = []
    for case in root.iter("testcase"):
        classname = case.get("classname") or "unknown"
        if "__main__." in classname:
            classname = classname[classname.find("__main__.") + 9:]
        try:
            time = float(case.get("time") or 0.0)
        except ValueError:
            time = 0.0
        cases.append(CaseResult(
            name="%s/%s" % (prefix, case.get("name") or "unknown"), classname=classname, time=time,
            failures=tuple(_text(f) for f in case.findall("failure")),
            errors=tuple(_text(e) for e in case.findall("error")),
            skipped=case.find("skipped") is not None or case.get("status") == "notrun"))
    return tuple(cases)


def judge(test_name: str, returncode: int | None, timed_out: bool, time_limit: float, result_file: str,
          elapsed: float, attempts: int, text: bool = False, prefix: str | None = None) -> TestOutcome:
    """A test's outcome from how its process ended and what it wrote (`text`: rostest's --text, no results
    are written, the exit status alone decides)."""
    problem = None
    cases: tuple[CaseResult, ...] = ()
    if os.path.isfile(result_file):
        try:
            cases = read_result_file(result_file, prefix)
        except ValueError as e:
            problem = str(e)
    if timed_out:
        problem = "test [%s] timed out after %g s (time-limit)" % (test_name, time_limit)
    elif returncode is not None and returncode < 0:
        problem = "test [%s] died by signal %s" % (test_name, signal_name(-returncode))
    elif returncode and not any(c.failures or c.errors for c in cases):
        # (unittest and gtest exit 1 when a case failed: that failure is the result, not a problem of the run)
        problem = "test [%s] exited with code %d" % (test_name, returncode)
    elif text:
        pass
    elif problem is None and not os.path.isfile(result_file):
        problem = "test [%s] did not generate test results" % test_name
    elif problem is None and not cases:
        problem = "test [%s] results [%s] hold no test case" % (test_name, result_file)
    return TestOutcome(test_name, cases, problem, elapsed, attempts, result_file if os.path.isfile(result_file) else None)


def signal_name(num: int) -> str:
    import signal
    try:
        return signal.Signals(num).name
    except ValueError:
        return str(num)


def write_junit(path: str, suite_name: str, runs: list[TestOutcome]) -> None:
    """rostest's `rostest-<file>.xml`: one `rostest` case per `<test>` (failed when the test did not run
    cleanly), then every test's own cases, in one `<testsuite>` whose counts are the cases'."""
    cases = []
    for run in runs:
        case = etree.Element("testcase", classname="rostest.runner.RosTest", name="test%s" % run.test_name,
                             time="%.4f" % run.time)
        if run.problem is not None:
            etree.SubElement(case, "failure", type="RostestFailure", message=run.problem).text = run.problem
        cases.append(case)
        for c in run.cases:
            sub = etree.Element("testcase", classname=c.classname, name=c.name, time="%.4f" % c.time)
            for text in c.failures:
                etree.SubElement(sub, "failure", type="failure", message=text.split("\n", 1)[0]).text = text
            for text in c.errors:
                etree.SubElement(sub, "error", type="error", message=text.split("\n", 1)[0]).text = text
            if c.skipped:
                etree.SubElement(sub, "skipped")
            cases.append(sub)
    failures = sum(1 for c in cases if c.find("failure") is not None)
    errors = sum(1 for c in cases if c.find("error") is not None and c.find("failure") is None)
    suite = etree.Element("testsuite", name=suite_name, tests=str(len(cases)), failures=str(failures),
                          errors=str(errors), time="%.3f" % sum(r.time for r in runs))
    suite.extend(cases)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp%d" % os.getpid()
    etree.ElementTree(suite).write(tmp, encoding="utf-8", xml_declaration=True, pretty_print=True)
    os.replace(tmp, path)


def write_test_file_failure(path: str, outname: str, message: str) -> None:
    """rostest's result for a test file it cannot run (its write_bad_filename_failure, #1140): one failed
    `Results.test_ran` case whose message says why."""
    suite = etree.Element("testsuite", tests="1", failures="1", time="1", errors="0", name=outname)
    case = etree.SubElement(suite, "testcase", name="test_ran", status="run", time="1", classname="Results")
    etree.SubElement(case, "failure", message=message, type="")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp%d" % os.getpid()
    etree.ElementTree(suite).write(tmp, encoding="UTF-8", xml_declaration=True, pretty_print=True)
    os.replace(tmp, path)


def summary(runs: list[TestOutcome]) -> str:
    """rostest's summary (each case, then RESULT and counts), with the reason of every test that did not run cleanly."""
    out = ["[ROSTEST]" + "-" * 71, ""]
    for run in runs:
        for c in run.cases:
            if c.passed:
                out.append("[%s][passed]" % c.name)
                continue
            for kind, texts in (("FAILURE", c.failures), ("ERROR", c.errors)):
                for text in texts:
                    head = "[%s][%s]" % (c.name, kind)
                    out += [head + "-" * (80 - len(head)), text, "-" * 80, ""]
    for run in runs:
        if run.problem is not None:
            out.append("[test%s][failed]" % run.test_name)
    failed_runs = [r for r in runs if r.problem is not None]
    tests = sum(len(r.cases) for r in runs) + len(failed_runs)
    failures = sum(r.failures for r in runs) + len(failed_runs)
    errors = sum(r.errors for r in runs)
    ok = failures == 0 and errors == 0
    out += ["", "SUMMARY",
            "\033[32m * RESULT: SUCCESS\033[0m" if ok else "\033[1;31m * RESULT: FAIL\033[0m",
            " * TESTS: %d" % tests,
            (" * ERRORS: %d" % errors) if not errors else "\033[1;31m * ERRORS: %d\033[0m" % errors,
            (" * FAILURES: %d" % failures) if not failures else "\033[1;31m * FAILURES: %d\033[0m" % failures]
    if failed_runs:
        out += ["", "ERROR: The following tests failed to run:"]
        out += [" * test%s: %s" % (r.test_name, r.problem) for r in failed_runs]
    return "\n".join(out) + "\n"
