"""Test hosts for the multi-machine tests: network namespaces on one bridge, each running Debian's sshd.

Each host is a network namespace joined to a bridge in the root namespace by a
veth link, on a private subnet (10.77.K.0/24: the bridge is .1, host i is
.i+1), so that traffic stays between these hosts and this machine. Every host
runs Debian's `/usr/sbin/sshd` with a config of its own (no PAM, root login by
a key made for the test, its own host key). The namespaces share the
filesystem, so Debian's ROS and this worktree are "installed" on every host.

Each host's root has a home of its own, as on separate computers: a fresh
account's (Debian's /etc/skel). `ip netns exec` bind-mounts the files of
/etc/netns/NAME/ over /etc, so the host's sshd reads a passwd whose root home
is that directory. (Logging in with this machine's /root would share its shell
start-up files between the hosts: here root's ~/.bashrc runs `pyenv init`,
whose `pyenv rehash` takes a lock in /root/.pyenv that made logins to two
"computers" at once wait for each other; nodes' ~/.ros would be shared too.)

For the client side the helper writes an `ssh_config` (identity, known_hosts
holding the hosts' keys, BatchMode) that the launcher is pointed at through
`LAUNCHER_SSH_COMMAND`, and a `home` directory with the same key and
known_hosts under `.ssh/` for Debian's roslaunch (paramiko reads `~`, i.e. `HOME`).

Everything is undone by `close()`: processes left in a namespace are killed
(that a test expects none is checked before), namespaces, links and bridge deleted.
Needs root (CI runs as root) and `openssh-server`; `TestHosts.unavailable()` says why not.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import tempfile
import time

SSHD = "/usr/sbin/sshd"
SUBNET_PREFIX = "10.77"


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=30)


class TestHost:
    """One namespace: its name, address, env-loader, and the root-side end of its link."""

    __test__ = False

    def __init__(self, index: int, netns: str, address: str, link: str, env_loader: str):
        self.index = index
        self.netns = netns
        self.address = address
        self.link = link  # the veth end in the root namespace: `down` cuts the host off
        self.env_loader = env_loader
        self.home = ""  # the login user's home on this host
        self.sshd: subprocess.Popen | None = None

    def pids(self) -> list[int]:
        """Processes running on the host, its sshd listener left out."""
        out = _ip("netns", "pids", self.netns, check=False).stdout.split()
        skip = {self.sshd.pid} if self.sshd is not None else set()
        return [int(p) for p in out if p.isdigit() and int(p) not in skip and os.path.exists("/proc/%s" % p)]

    def process_lines(self) -> list[str]:
        """`pid command line` of each process on the host (for assertion messages)."""
        lines = []
        for pid in self.pids():
            try:
                with open("/proc/%d/cmdline" % pid, "rb") as f:
                    lines.append("%d %s" % (pid, f.read().replace(b"\0", b" ").decode(errors="replace").strip()))
            except OSError:
                pass
        return lines

    def cut(self) -> None:
        _ip("link", "set", self.link, "down")

    def restore(self) -> None:
        _ip("link", "set", self.link, "up")

    def run(self, argv: list[str], **kw) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", self.netns, *argv], **kw)


class TestHosts:
    """`count` test hosts; use as a context manager (or call close())."""

    __test__ = False  # (pytest: not a test class)

    def __init__(self, count: int = 2, *, client_alive: bool = False, env: dict[str, str] | None = None):
        self.dir = tempfile.mkdtemp(prefix="launcher-hosts-")
        self.hosts: list[TestHost] = []
        self.bridge = ""
        self.subnet = ""
        self.gateway = ""  # this machine's address on the test subnet
        self._client_alive = client_alive
        self._env = dict(env or {})  # what each host's env-loader exports besides PATH and ROS_IP
        try:
            self._setup(count)
        except BaseException:
            self.close()
            raise

    @staticmethod
    def unavailable() -> str | None:
        """None if test hosts can be made here, else why not."""
        if os.geteuid() != 0:
            return "test hosts need root (network namespaces, sshd)"
        for tool in ("ip", "ssh", "ssh-keygen", "ssh-keyscan"):
            if shutil.which(tool) is None:
                return "%s is not installed" % tool
        if not os.path.exists(SSHD):
            return "%s is not installed (apt-get install openssh-server)" % SSHD
        return None

    # ---- set-up -------------------------------------------------------------------------------------

    def _claim_subnet(self) -> int:
        """A subnet no address of this machine is on, claimed by making its bridge: the bridge's name is the lock
        (two test runs at once, a whole suite on two Pythons side by side, may find the same subnet free; one makes
        it)."""
        used = _ip("-o", "-4", "addr").stdout
        for k in range(100, 250):
            if " %s.%d." % (SUBNET_PREFIX, k) not in used and \
                    _ip("link", "add", "lt%dbr" % k, "type", "bridge", check=False).returncode == 0:
                return k
        raise RuntimeError("no free %s.K.0/24 subnet" % SUBNET_PREFIX)

    def _setup(self, count: int) -> None:
        k = self._claim_subnet()
        tag = "lt%d" % k
        self.subnet = "%s.%d" % (SUBNET_PREFIX, k)
        self.gateway = self.subnet + ".1"
        self.bridge = tag + "br"
        _ip("addr", "add", self.gateway + "/24", "dev", self.bridge)
        _ip("link", "set", self.bridge, "up")
        self._keys()
        os.makedirs("/run/sshd", exist_ok=True)  # sshd's privilege separation directory
        for i in range(1, count + 1):
            netns, link, address = "%sh%d" % (tag, i), "%sv%d" % (tag, i), "%s.%d" % (self.subnet, i + 1)
            _ip("netns", "add", netns)
            host = TestHost(i, netns, address, link, os.path.join(self.dir, "env-%d.sh" % i))
            self.hosts.append(host)
            _ip("link", "add", link, "type", "veth", "peer", "name", "eth0", "netns", netns)
            _ip("link", "set", link, "master", self.bridge)
            _ip("link", "set", link, "up")
            _ip("-n", netns, "addr", "add", address + "/24", "dev", "eth0")
            _ip("-n", netns, "link", "set", "eth0", "up")
            _ip("-n", netns, "link", "set", "lo", "up")
            with open(host.env_loader, "w") as f:
                # what a robot's env-loader does: the ROS environment, and this host's own address
                f.write("#!/bin/sh\nexport PATH=/usr/bin:/bin:/usr/sbin:/sbin\nexport ROS_IP=%s\n"
                        "unset ROS_HOSTNAME\n%sexec \"$@\"\n"
                        % (address, "".join("export %s=%s\n" % (k, shlex.quote(v)) for k, v in self._env.items())))
            os.chmod(host.env_loader, 0o755)
            self._own_home(host)
            self._start_sshd(host)
        self._client_files()

    def _keys(self) -> None:
        for name in ("host_key", "client_key", "other_key"):
            subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-C", "launcher-test",
                            "-f", os.path.join(self.dir, name)], check=True, capture_output=True, timeout=60)
        shutil.copy(os.path.join(self.dir, "client_key.pub"), os.path.join(self.dir, "authorized_keys"))

    def _own_home(self, host: TestHost) -> None:
        """A root home for the host alone: /etc/netns/NAME/passwd names it (see the module docstring)."""
        host.home = os.path.join(self.dir, "root-%d" % host.index)
        shutil.copytree("/etc/skel", host.home)
        with open("/etc/passwd") as f:
            entries = [line.split(":") for line in f.read().splitlines()]
        etc = os.path.join("/etc/netns", host.netns)
        os.makedirs(etc, exist_ok=True)
        with open(os.path.join(etc, "passwd"), "w") as f:
            for e in entries:
                if len(e) == 7 and e[2] == "0":
                    e[5] = host.home
                f.write(":".join(e) + "\n")

    def _start_sshd(self, host: TestHost) -> None:
        config = os.path.join(self.dir, "sshd-%d.conf" % host.index)
        with open(config, "w") as f:
            f.write("ListenAddress %s\nPort 22\nHostKey %s\nAuthorizedKeysFile %s\nUsePAM no\n"
                    "PermitRootLogin prohibit-password\nPasswordAuthentication no\n"
                    "KbdInteractiveAuthentication no\nStrictModes no\nPidFile %s\nLogLevel ERROR\n"
                    "AcceptEnv none\n%s"
                    % (host.address, os.path.join(self.dir, "host_key"), os.path.join(self.dir, "authorized_keys"),
                       os.path.join(self.dir, "sshd-%d.pid" % host.index),
                       "ClientAliveInterval 1\nClientAliveCountMax 2\n" if self._client_alive else ""))
        host.sshd = subprocess.Popen(["ip", "netns", "exec", host.netns, SSHD, "-D", "-e", "-f", config],
                                     stdout=subprocess.DEVNULL, stderr=open(os.path.join(self.dir, "sshd-%d.log"
                                                                                         % host.index), "w"))
        deadline = time.monotonic() + 20
        while True:
            r = host.run(["ssh-keyscan", "-T", "2", host.address], capture_output=True, text=True, timeout=30)
            if r.stdout.strip():
                break
            if host.sshd.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("sshd did not start on %s: %s" % (host.netns, open(
                    os.path.join(self.dir, "sshd-%d.log" % host.index)).read()))
            time.sleep(0.05)

    def _client_files(self) -> None:
        with open(os.path.join(self.dir, "host_key.pub")) as f:
            key = " ".join(f.read().split()[:2])
        self.known_hosts = os.path.join(self.dir, "known_hosts")
        with open(self.known_hosts, "w") as f:
            for h in self.hosts:
                f.write("%s %s\n" % (h.address, key))
        self.ssh_config = os.path.join(self.dir, "ssh_config")
        with open(self.ssh_config, "w") as f:
            # (the identity is given by ssh_command's -i: IdentitiesOnly makes it the only one offered)
            f.write("Host *\n  User root\n  IdentitiesOnly yes\n  UserKnownHostsFile %s\n"
                    "  GlobalKnownHostsFile /dev/null\n  StrictHostKeyChecking yes\n  ConnectTimeout 5\n"
                    % self.known_hosts)
        # Debian's roslaunch (paramiko) reads ~/.ssh: a home of its own
        self.home = os.path.join(self.dir, "home")
        ssh_dir = os.path.join(self.home, ".ssh")
        os.makedirs(ssh_dir)
        shutil.copy(os.path.join(self.dir, "client_key"), os.path.join(ssh_dir, "id_ed25519"))
        shutil.copy(self.known_hosts, os.path.join(ssh_dir, "known_hosts"))

    # ---- use ----------------------------------------------------------------------------------------

    def ssh_command(self, *, key: str = "client_key", known_hosts: str | None = None) -> str:
        """The `LAUNCHER_SSH_COMMAND` that reaches the hosts (another key: one they refuse)."""
        cmd = "ssh -F %s -i %s" % (self.ssh_config, os.path.join(self.dir, key))
        if known_hosts is not None:
            cmd += " -o UserKnownHostsFile=%s" % known_hosts
        return cmd

    def env(self, **extra: str) -> dict[str, str]:
        """An environment for a launcher run by these tests: our address on the subnet, the ssh command."""
        env = dict(os.environ)
        env.pop("ROS_HOSTNAME", None)
        env["ROS_IP"] = self.gateway
        env["LAUNCHER_SSH_COMMAND"] = self.ssh_command()
        env.update(extra)
        return env

    def close(self) -> None:
        for host in self.hosts:
            for pid in host.pids():
                try:
                    os.kill(pid, signal.SIGKILL)
                except OSError:
                    pass
            if host.sshd is not None:
                host.sshd.kill()
                host.sshd.wait()
            _ip("netns", "del", host.netns, check=False)
            shutil.rmtree(os.path.join("/etc/netns", host.netns), ignore_errors=True)
            _ip("link", "del", host.link, check=False)
        if self.bridge:
            _ip("link", "del", self.bridge, check=False)
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> TestHosts:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
