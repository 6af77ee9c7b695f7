"""`launcher report [--run ID] [-o FILE]`: one `.tar.gz` of a run to attach to a bug report, with its secrets left out.

What a developer asks for when something went wrong, from the run's log
directory (the last run by default; while it runs too): the events file, the
launch's log and console file, each node's output and log files (the last
MAX_FILE_BYTES of each, the archive at most MAX_TOTAL_BYTES), the parameters
the launch set as YAML and its record (services/runrecord.py wrote both there
at its start: the master that held the parameters may be gone), the launch
files and the YAML files they loaded, versions (launcher, Python, the OS, the
ROS packages found), the environment variables that matter to ROS, and for
each core dump a node left (the launch log names it) its backtrace from gdb
rather than the core. `manifest.json` says what is in it, what was cut or left
out and why.

Secrets are kept out of every file written or copied: the run's token (its
`launcher-token` is never copied; its value is removed wherever it appears, a
console line that printed the token-bearing address included), and the values
of environment variables and parameters whose names say password, token, secret
or key (SECRET_NAME): replaced in the environment and the parameters, and
removed wherever else they appear (a launch file that sets one, the launch
log's notes). The manifest lists the names.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import tarfile
import time
from typing import Any, Iterable

from launcher import __version__
from launcher.fleet.state import EVENTS_FILE
from launcher.model.token import TOKEN_FILE
from launcher.operate import client, lastrun
from launcher.workspace.packages import PackageIndex
from launcher.workspace.roshome import PARAMS_FILE, RUN_RECORD_FILE, ros_environment

MAX_FILE_BYTES = 10 * 1000 * 1000  # of one file: its last 10 MB (a node's output ends with what went wrong)
MAX_TOTAL_BYTES = 200 * 1000 * 1000  # of all files together (before compression)
SECRET_NAME = re.compile(r"password|passwd|token|secret|key", re.IGNORECASE)
REMOVED = "[removed by launcher report]"
MIN_SECRET_LEN = 4  # a shorter value ("1", "on") is not searched for in the other files: it would cut them to pieces
CORE_LINE = re.compile(r"\[(?P<process>[^\]]+)\] dumped core \(signal (?P<signal>\d+)\): (?P<where>.*)")
NODE_LINE = re.compile(r"\[launch\] node \[(?P<node>[^\]]+)\] \(process (?P<process>[^)]+)\): (?P<command>.*)")
CORE_PACKAGES = ("roscpp", "rospy", "roslaunch", "rosmaster", "rosout", "rosbag", "rosgraph", "rosconsole")
GDB_TIMEOUT_S = 60.0


class Secrets:
    """What is removed from every file of the archive: the token, and the values of secret-named variables and
    parameters (their names kept for the manifest)."""

    def __init__(self, token: str = ""):
        self.values: set[str] = set()
        self.names: list[str] = []
        if token:
            self.values.add(token)

    def secret(self, name: str, value: Any, shown_name: str = "") -> bool:
        """Whether `name` says a secret; if so its value is noted (its text will be removed from every file) and
        its name (`shown_name`, a parameter's full key) kept for the manifest."""
        if not SECRET_NAME.search(name):
            return False
        self.names.append(shown_name or name)
        for text in _texts(value):
            if len(text) >= MIN_SECRET_LEN:
                self.values.add(text)
        return True

    def scrub(self, data: bytes) -> bytes:
        for value in sorted(self.values, key=len, reverse=True):  # (a longer secret containing a shorter one first)
            data = data.replace(value.encode("utf-8", "replace"), REMOVED.encode())
        return data


def _texts(value: Any) -> Iterable[str]:
    """The texts of a value (a parameter may be a list or a map of them)."""
    if isinstance(value, dict):
        for v in value.values():
            yield from _texts(v)
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _texts(v)
    elif isinstance(value, bytes):
        yield value.decode("utf-8", "replace")
    elif value is not None and not isinstance(value, bool):
        yield str(value)


def redact_params(value: Any, secrets: Secrets, key: str = "") -> Any:
    """The parameters with the value of each secret-named one (at any depth) replaced."""
    if not isinstance(value, dict):
        return value
    out = {}
    for k, v in value.items():
        full = str(k) if str(k).startswith("/") else "%s/%s" % (key.rstrip("/"), k)
        out[k] = REMOVED if secrets.secret(full.rstrip("/").rpartition("/")[2], v, full) \
            else redact_params(v, secrets, full)
    return out


def tail(path: str, limit: int) -> tuple[bytes, int]:
    """The last `limit` bytes of a file, from a line's start (a secret is never cut in two at the edge), and its size."""
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size <= limit:
            return f.read(), size
        f.seek(size - limit - 1)
        data = f.read(limit + 1)
    newline = data.find(b"\n")  # (the byte before the cut is read too: a cut at a line's start keeps that line)
    return (data[newline + 1:] if newline >= 0 else b""), size


class Archive:
    """The archive being written: members under one top directory, the budget, and the manifest's entries."""

    def __init__(self, path: str, top: str, secrets: Secrets):
        self.tar = tarfile.open(path, "w:gz")
        self.top = top
        self.secrets = secrets
        self.total = 0
        self.files: list[dict[str, Any]] = []
        self.left_out: list[dict[str, str]] = []

    def add_bytes(self, name: str, data: bytes, source: str = "", size: int | None = None) -> None:
        data = self.secrets.scrub(data)
        if self.total + len(data) > MAX_TOTAL_BYTES:
            self.left_out.append({"name": name, "source": source, "why": "the archive's limit of %d bytes"
                                  % MAX_TOTAL_BYTES})
            return
        info = tarfile.TarInfo("%s/%s" % (self.top, name))
        info.size, info.mtime, info.mode = len(data), int(time.time()), 0o644
        self.tar.addfile(info, io.BytesIO(data))
        self.total += len(data)
        entry: dict[str, Any] = {"name": name, "bytes": len(data)}
        if source:
            entry["source"] = source
        if size is not None and size > MAX_FILE_BYTES:
            entry["truncated"] = "the last %d of %d bytes" % (MAX_FILE_BYTES, size)
        self.files.append(entry)

    def add_file(self, name: str, path: str) -> None:
        try:
            data, size = tail(path, MAX_FILE_BYTES)
        except OSError as e:
            self.left_out.append({"name": name, "source": path, "why": e.strerror or str(e)})
            return
        self.add_bytes(name, data, path, size)

    def add_text(self, name: str, text: str) -> None:
        self.add_bytes(name, text.encode("utf-8"))

    def close(self) -> None:
        self.tar.close()


def _read_json(path: str) -> dict:
    try:
        with open(path, encoding="utf-8") as f:
            value = json.load(f)
        return value if isinstance(value, dict) else {}
    except (OSError, ValueError):
        return {}


def _token(run_dir: str) -> str:
    try:
        with open(os.path.join(run_dir, TOKEN_FILE), encoding="ascii", errors="replace") as f:
            return f.read().strip()
    except OSError:
        return ""


def _package_version(path: str) -> str:
    try:
        with open(os.path.join(path, "package.xml"), encoding="utf-8", errors="replace") as f:
            m = re.search(r"<version[^>]*>\s*([^<\s]+)\s*</version>", f.read())
    except OSError:
        return ""
    return m.group(1) if m else ""


def versions(run: dict, environ: dict[str, str]) -> dict[str, Any]:
    """launcher, Python, the OS, and each ROS package the run's nodes use (and ROS's core ones): path and version."""
    os_name = ""
    try:
        with open("/etc/os-release", encoding="utf-8") as f:
            os_name = dict(line.rstrip("\n").partition("=")[::2] for line in f if "=" in line).get(
                "PRETTY_NAME", "").strip('"')
    except OSError:
        pass
    index = PackageIndex(dict(environ, **{k: v for k, v in run.get("environment", {}).items()
                                          if k in ("ROS_PACKAGE_PATH", "CMAKE_PREFIX_PATH")}))
    packages = {}
    for pkg in list(run.get("packages", [])) + [p for p in CORE_PACKAGES if p not in run.get("packages", [])]:
        try:
            path = index.get_path(pkg)
        except Exception:  # noqa: BLE001 - not found here: said as such
            packages[pkg] = {"found": False}
            continue
        packages[pkg] = {"path": path, "version": _package_version(path)}
    return {"launcher": __version__, "launcher_of_the_run": run.get("launcher", ""), "python": sys.version.split()[0],
            "python_of_the_run": run.get("python", ""), "os": os_name, "platform": platform.platform(),
            "ros_distro": run.get("environment", {}).get("ROS_DISTRO", environ.get("ROS_DISTRO", "")),
            "packages": packages}


def core_dumps(launch_logs: list[str]) -> list[dict[str, str]]:
    """The cores the launch logs name: process, signal, where, and the node's executable (from its command line)."""
    commands: dict[str, str] = {}
    cores = []
    for path in launch_logs:
        try:
            with open(path, encoding="utf-8", errors="replace") as f:
                for line in f:
                    m = NODE_LINE.search(line)
                    if m:
                        commands[m.group("process")] = m.group("command")
                        continue
                    m = CORE_LINE.search(line)
                    if m:
                        cores.append(m.groupdict())
        except OSError:
            continue
    for core in cores:
        try:
            words = shlex.split(commands.get(core["process"], ""))
        except ValueError:
            words = commands.get(core["process"], "").split()
        core["executable"] = executable(words[0]) if words else ""
    return cores


def executable(path: str) -> str:
    """The program that dumped the core: `path`, or the interpreter its `#!` line names (a script's core is its
    interpreter's: gdb needs that one's symbols)."""
    try:
        with open(path, "rb") as f:
            first = f.readline(256)
    except OSError:
        return path
    if not first.startswith(b"#!"):
        return path
    words = first[2:].decode("utf-8", "replace").split()
    if not words:
        return path
    if os.path.basename(words[0]) == "env" and len(words) > 1:
        return shutil.which(words[1]) or words[1]
    return words[0]


def backtrace(core: dict[str, str]) -> str:
    """The core's backtrace (gdb), or why there is none."""
    where = core["where"]
    m = re.match(r"core dumped to (/\S+)", where)
    if m:
        gdb = shutil.which("gdb")
        if gdb is None:
            return "gdb is not installed: no backtrace of %s (apt-get install gdb)\n" % m.group(1)
        argv = [gdb, "-batch", "-nx", "-ex", "thread apply all bt"] + ([core["executable"]] if core["executable"] else []) \
            + ["-c", m.group(1)]
    else:
        m = re.match(r"get it with: coredumpctl gdb (\d+)", where)
        if not m or shutil.which("coredumpctl") is None:
            return "no backtrace: %s\n" % where
        argv = ["coredumpctl", "info", "--no-pager", m.group(1)]
    try:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=GDB_TIMEOUT_S, stdin=subprocess.DEVNULL)
    except (OSError, subprocess.TimeoutExpired) as e:
        return "%s failed: %s\n" % (" ".join(argv), e)
    return "$ %s\n%s%s" % (" ".join(shlex.quote(a) for a in argv), done.stdout, done.stderr)


def _params_yaml(run_dir: str, secrets: Secrets) -> tuple[str, str]:
    """(the parameters as YAML with secrets replaced, why there are none)."""
    path = os.path.join(run_dir, PARAMS_FILE)
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except OSError as e:
        return "", "%s: %s (a run of another launcher or of roslaunch: its parameters were not recorded)" % (
            path, e.strerror)
    import yaml  # (PyYAML: only a report pays for it)
    try:
        params = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        return "", "%s does not read as YAML: %s" % (path, e)
    redacted = redact_params(params, secrets) if isinstance(params, dict) else params
    return yaml.safe_dump(redacted, default_flow_style=False, sort_keys=True, allow_unicode=True), ""


def make(run_dir: str, out: str, environ: dict[str, str], latest: bool) -> dict[str, Any]:
    """Write the archive of the run in `run_dir` to `out`; its manifest."""
    run_id = os.path.basename(run_dir)
    run = _read_json(os.path.join(run_dir, RUN_RECORD_FILE))
    secrets = Secrets(_token(run_dir))
    # the environment: the run's (its record), else this shell's
    env = run.get("environment") or ros_environment(environ)
    shown_env = {k: (REMOVED if secrets.secret(k, v) else v) for k, v in env.items()}
    for k, v in environ.items():  # (this shell's secrets too: a node of the run may have printed them)
        if k not in env and SECRET_NAME.search(k):
            secrets.secret(k, v, "%s (of the shell running the report)" % k)
    params, params_missing = _params_yaml(run_dir, secrets)
    top = "launcher-report-%s" % run_id
    archive = Archive(out, top, secrets)
    try:
        try:
            entries = sorted(os.listdir(run_dir))
        except OSError as e:
            raise client.ToolError("cannot read %s: %s" % (run_dir, e.strerror)) from None
        launch_logs = [os.path.join(run_dir, e) for e in entries if lastrun.LAUNCH_LOG.fullmatch(e)]
        # the run's own files first (the events, the launch's log and console), then the nodes' (smallest first:
        # a huge one spends the budget last)
        first = [EVENTS_FILE] + [os.path.basename(p) for p in launch_logs] + ["launch-console.log", "master.log",
                                                                              "rosout.log"]
        rest = [e for e in entries if e not in first and e not in (TOKEN_FILE, PARAMS_FILE, RUN_RECORD_FILE)
                and os.path.isfile(os.path.join(run_dir, e))]
        rest.sort(key=lambda e: _size(os.path.join(run_dir, e)))
        if params:
            archive.add_text("params.yaml", params)
        archive.add_text("environment.json", json.dumps(shown_env, indent=1, sort_keys=True) + "\n")
        archive.add_text("versions.json", json.dumps(versions(run, environ), indent=1) + "\n")
        if run:
            shown_run = dict(run, environment=shown_env)
            archive.add_text("run.json", json.dumps(shown_run, indent=1, default=str) + "\n")
        for name in first + rest:
            path = os.path.join(run_dir, name)
            if os.path.isfile(path):
                archive.add_file("log/" + name, path)
        for path in list(run.get("launch_files", [])) + list(run.get("yaml_files", [])):
            archive.add_file("files" + os.path.abspath(path), path)
        for core in core_dumps(launch_logs):
            archive.add_text("backtraces/%s.txt" % re.sub(r"[^\w.-]", "_", core["process"]),
                             "%s: signal %s, %s\n\n%s" % (core["process"], core["signal"], core["where"],
                                                          backtrace(core)))
        manifest = {"run_id": run_id, "run_dir": run_dir, "latest": latest, "made": time.strftime(
                    "%Y-%m-%d %H:%M:%S %z"), "launcher": __version__,
                    "limits": {"bytes_per_file": MAX_FILE_BYTES, "bytes_in_all": MAX_TOTAL_BYTES,
                               "per_file": "the last %d bytes of each file (from a line's start)" % MAX_FILE_BYTES},
                    "secrets_removed": {"token": bool(_token(run_dir)),
                                        "names": sorted(set(secrets.names)),
                                        "rule": "the run's token, and the values of environment variables and "
                                                "parameters whose names say password, token, secret or key, "
                                                "replaced by %r in every file" % REMOVED},
                    "files": archive.files, "left_out": archive.left_out + [{"name": TOKEN_FILE, "why": "the run's token"}]}
        if params_missing:
            manifest["params_missing"] = params_missing
        if not run:
            manifest["record_missing"] = "%s has no %s: no launch files, YAML files or packages of the run" % (
                run_dir, RUN_RECORD_FILE)
        archive.add_text("manifest.json", json.dumps(manifest, indent=1) + "\n")
    finally:
        archive.close()
    return manifest


def _size(path: str) -> int:
    try:
        return os.stat(path).st_size
    except OSError:
        return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher report", description="one .tar.gz of a run (the last one by "
                                "default) to attach to a bug report: events, logs, output, parameters, files, "
                                "versions; the run's token and secret-named values left out")
    p.add_argument("--run", metavar="RUN_ID", help="the run (default: the last one, ROS_LOG_DIR/latest)")
    p.add_argument("-o", "--output", metavar="FILE", help="the archive (default: ./launcher-report-RUN_ID.tar.gz)")
    return p


def _main(argv: list[str]) -> int:
    opts = parser().parse_args(argv)
    environ = dict(os.environ)
    run_dir = lastrun.find_run(environ, opts.run)
    out = opts.output or "launcher-report-%s.tar.gz" % os.path.basename(run_dir)
    try:
        manifest = make(run_dir, out, environ, latest=not opts.run)
    except OSError as e:
        raise client.ToolError("cannot write %s: %s" % (out, e.strerror or e)) from None
    cut = [f["name"] for f in manifest["files"] if "truncated" in f]
    over = [f["name"] for f in manifest["left_out"] if f["name"] != TOKEN_FILE]
    print("wrote %s: %d files of the run %s%s%s (manifest.json says what is in it)" % (
        out, len(manifest["files"]), manifest["run_id"],
        "; cut to their last %d MB: %s" % (MAX_FILE_BYTES // 1000000, ", ".join(cut)) if cut else "",
        "; left out: %s" % ", ".join(over) if over else ""))
    return client.EXIT_OK


def main(argv: list[str]) -> int:
    return client.run_tool(_main, argv)
