"""The `launch` command line: the argparse-free reading of simple command lines is argparse's reading."""

from __future__ import annotations

import subprocess
import sys

import pytest

from launcher.cli import launch as cli


def _argparse(argv: list[str]) -> dict:
    return vars(cli.build_parser().parse_intermixed_args(argv))


def test_defaults_and_flags_are_the_parsers():
    parser = cli.build_parser()
    defaults = {a.dest: a.default for a in parser._actions if a.dest not in ("help", "version", "positional")}
    assert {k: v for k, v in cli._DEFAULTS.items()} == defaults
    store_true = {s: a.dest for a in parser._actions if a.__class__.__name__ == "_StoreTrueAction"
                  for s in a.option_strings}
    # every flag read without argparse is a store_true option of the parser, under the same name
    assert {s: d for s, d in store_true.items() if s in cli._FLAGS} == cli._FLAGS


@pytest.mark.parametrize("argv", [
    ["--nodes", "a.launch"], ["a.launch", "--dump-params"], ["pkg", "f.launch", "x:=1", "--files", "__ns:=/r"],
    ["-v", "--screen", "--log", "--required", "--wait", "--local", "--no-summary", "--skip-log-check",
     "--disable-title", "f.launch"], ["--core"], ["-", "--nodes"], [], ["--ros-args", "f.launch", "a:=b c"],
])
def test_simple_command_lines_read_as_argparse_reads_them(argv):
    opts = cli.parse_simple_args(argv)
    assert opts is not None and vars(opts) == _argparse(argv)


@pytest.mark.parametrize("argv", [
    ["--args", "/n", "f.launch"], ["--find-node=/n", "f.launch"], ["-p", "11312", "--core"], ["-h"], ["--version"],
    ["--node", "f.launch"], ["--nodes", "--", "-f.launch"], ["-vv"], ["--sigint-timeout", "3", "f.launch"],
])
def test_anything_else_goes_to_argparse(argv):
    assert cli.parse_simple_args(argv) is None


def test_command_lines_only_argparse_reads_keep_its_errors():
    out = subprocess.run([sys.executable, "-m", "launcher", "--bogus"], capture_output=True, text=True)
    assert out.returncode == 2 and "unrecognized arguments: --bogus" in out.stderr
    out = subprocess.run([sys.executable, "-m", "launcher", "--nodes"], capture_output=True, text=True)
    assert out.returncode == 1 and "you must specify at least one input file" in out.stderr


def test_the_fatal_error_is_the_most_visible_line_on_a_terminal(tmp_path):
    """On a terminal the error that ends the launch is bold red, and it comes after the warnings before it."""
    import os
    import pty
    import subprocess
    import sys
    f = tmp_path / "bad.launch"
    f.write_text('<launch>\n<node pkg="nopkg" type="x" name="n" bogus="1"/>\n'
                 '<include file="%s/missing.launch"/>\n</launch>\n' % tmp_path)
    primary, secondary = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "--nodes", str(f)], stdout=secondary, stderr=secondary)
    os.close(secondary)
    out = b""
    while True:
        try:
            chunk = os.read(primary, 4096)
        except OSError:  # the terminal's other side closed: the launch has exited
            break
        if not chunk:
            break
        out += chunk
    os.close(primary)
    assert proc.wait(30) == 1
    text = out.decode()
    warning = text.index("unknown <node> attribute 'bogus'")
    fatal = text.index("\x1b[1;31m%s:3: included file" % f)
    assert warning < fatal


def test_an_input_file_that_does_not_exist_is_a_usage_error_as_in_roslaunch(tmp_path):
    """`launch robot.launch robot=r3` (a colon left out): roslaunch's parser.error, exit status 2, with the usage,
    and the argument it probably was."""
    f = tmp_path / "robot.launch"
    f.write_text('<launch><arg name="robot" default="r1"/></launch>')
    for argv in ([str(f), "robot=r3"], ["--nodes", str(f), "robot=r3"]):
        out = subprocess.run([sys.executable, "-m", "launcher"] + argv, capture_output=True, text=True, timeout=60)
        assert out.returncode == 2, out.stderr
        assert out.stderr.startswith("usage: launch [options]")
        assert out.stderr.endswith("launch: error: The following input files do not exist: robot=r3 (did you mean "
                                   "robot:=r3?)\n")


def test_did_you_mean_offers_files_only_where_a_file_is_asked_for(tmp_path):
    """`launch cam.launch` in a checkout: the directory `launcher` is no launch file to suggest; a file of a close
    name is, in the folder the command runs in and in the one a path names."""
    (tmp_path / "launcher").mkdir()
    (tmp_path / "camera.launch").mkdir()  # (a directory even with a launch file's name)

    def launch(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "launcher", *argv], capture_output=True, text=True, timeout=60,
                              cwd=str(tmp_path))

    out = launch("cam.launch")
    assert (out.returncode, out.stderr.strip().splitlines()[-1]) == (1, "[cam.launch] is not a launch file name"), \
        out.stderr
    (tmp_path / "cams.launch").write_text("<launch/>")
    for asked, hint in (("cam.launch", "cams.launch"), (str(tmp_path / "cam.launch"), "cams.launch")):
        out = launch(asked)
        assert out.stderr.strip().splitlines()[-1] == "[%s] is not a launch file name (did you mean %s?)" % (
            asked, hint), out.stderr


def test_the_run_options_are_the_command_lines_with_its_defaults():
    """A run reads typed options: every field comes from `launch`'s parsed command line, and a command line
    that says nothing gives RunOptions' own defaults (one set of defaults, not two)."""
    from launcher.model.runopts import RunOptions
    assert RunOptions.from_args(cli.build_parser().parse_args(["a.launch"])) == RunOptions(positional=("a.launch",))
    assert RunOptions.from_args(cli.parse_simple_args(["a.launch"])) == RunOptions(positional=("a.launch",))
    given = RunOptions.from_args(cli.build_parser().parse_args(
        ["--screen", "-p", "11400", "--sigint-timeout", "3", "--master-allow", "10.0.0.0/8", "a.launch", "x:=1"]))
    assert (given.screen, given.port, given.sigint_timeout, given.master_allow, given.positional) == (
        True, 11400, 3.0, ("10.0.0.0/8",), ("a.launch", "x:=1"))


def test_an_introspection_loads_with_the_collector_paused_and_leaves_it_as_it_was(tmp_path, monkeypatch, capsys):
    """The cyclic collector is paused for the imports and the load (their objects live to the end), and left as
    `launch` found it: running, or paused by a caller of its own."""
    import gc
    from launcher.cli import introspect
    f = tmp_path / "a.launch"
    f.write_text('<launch><node name="n" pkg="p" type="t"/></launch>')
    seen = []
    load = introspect.main
    monkeypatch.setattr(introspect, "main", lambda opts: seen.append(gc.isenabled()) or load(opts))
    assert gc.isenabled()
    try:
        assert cli.main(["--nodes", str(f)]) == 0
        assert (seen, gc.isenabled()) == ([False], True)
        gc.disable()
        assert cli.main(["--nodes", str(f)]) == 0
        assert (seen, gc.isenabled()) == ([False, False], False)
    finally:
        gc.enable()
    assert capsys.readouterr().out == "/n\n/n\n"


@pytest.mark.parametrize("argv", [["--core", "-p", "11399"], ["-c", "m1", "-u", "http://127.0.0.1:1/"]])
def test_a_run_imports_with_the_collector_paused_and_runs_with_it_running(argv, monkeypatch):
    """A run's modules (a remote child's too) are imported with the collector paused and then frozen (out of its
    way for good); the run itself has it running."""
    import gc
    from launcher.remote import child
    from launcher.run import runtime
    seen = []
    monkeypatch.setattr(runtime, "run", lambda opts, reading, exit_process: seen.append(
        (gc.isenabled(), gc.get_freeze_count())) or 0)
    monkeypatch.setattr(child, "run_child", lambda opts: seen.append((gc.isenabled(), gc.get_freeze_count())) or 0)
    importing = []
    imports = cli._import_asyncio_without_tls
    monkeypatch.setattr(cli, "_import_asyncio_without_tls", lambda: importing.append(gc.isenabled()) or imports())
    gc.unfreeze()
    try:
        assert cli.main(argv) == 0
        assert importing == [False]
        assert len(seen) == 1 and seen[0][0] is True and seen[0][1] > 0
    finally:
        gc.unfreeze()  # (as the run does at its end)
