"""The OpenSSH side of a remote machine: the `ssh` command line that runs a child, and its failures in words.

The system's own `ssh` client is used, so the user's `~/.ssh/config`
(`ProxyJump`, `User`, `IdentityFile`), the agent and `known_hosts` work as in
a terminal (roslaunch's paramiko misreads or ignores them: ros/ros_comm#612,
#1437, #2122). `BatchMode=yes`: nothing may prompt. `-tt` gives the remote
command a pty, so that when the connection closes (the launcher stopped,
killed, or the link timed out) the remote side gets SIGHUP and stops its nodes.

`LAUNCHER_SSH_COMMAND` replaces `ssh` (split as a shell would, like git's
`GIT_SSH_COMMAND`): another client, or options such as `-F config`.
"""

from __future__ import annotations

import re
import shlex
from typing import Mapping

from launcher.model.config import Machine
from launcher.model.errors import LaunchError

# ssh's own keep-alive: a link that is cut is noticed after INTERVAL * COUNT_MAX seconds
SERVER_ALIVE_INTERVAL_S = 1
SERVER_ALIVE_COUNT_MAX = 3
# the parent's heartbeat through the session (see remote_command)
# (a cut link's nodes must be gone within 5 s: TIMEOUT + S + NODE_GRACE ~ 4 s, and the launcher's loop
# never stalls anywhere near TIMEOUT, which would stop a healthy machine's nodes)
HEARTBEAT_S = 0.5
HEARTBEAT_TIMEOUT_S = 2.5
NODE_GRACE_S = 1.0  # after a cut, how long the nodes get to handle SIGINT
ORDERLY_END = b"q\n"  # the heartbeat that says the child was shut down and ends by itself (see remote_command)
ORDERLY_WAIT_S = 0.15
# the variable that marks every process a machine's session started (see remote_command)
SESSION_MARK = "LAUNCHER_SESSION"
SSH_FAILED = 255  # ssh's exit status for its own errors (the remote command's is passed through)


def check_machine(machine: Machine) -> None:
    """What OpenSSH cannot do for this `<machine>`: a LaunchError naming its file and line."""
    if machine.password:
        raise LaunchError("machine [%s]: password=\"...\" cannot be given to OpenSSH without a prompt; use a "
                          "key instead (ssh-copy-id %s%s) and remove the password attribute"
                          % (machine.name, machine.user + "@" if machine.user else "", machine.address),
                          machine.filename or None, machine.line or None)
    if not machine.env_loader:
        raise LaunchError("machine [%s]: env-loader is required to launch nodes on [%s]"
                          % (machine.name, machine.address), machine.filename or None, machine.line or None)


def remote_command(machine: Machine, program: str, child_name: str, parent_uri: str, run_id: str,
                   master_uri: str, sigint_timeout: float, sigterm_timeout: float) -> str:
    """The command the remote shell runs: roslaunch's (`env ROS_MASTER_URI=... ENV_LOADER roslaunch -c ...`)."""
    argv = ["env", "ROS_MASTER_URI=%s" % master_uri, machine.env_loader or "", program, "-c", child_name,
            "-u", parent_uri, "--run_id", run_id, "--sigint-timeout", str(sigint_timeout),
            "--sigterm-timeout", str(sigterm_timeout)]
    # (the mark is the watch loop's own pid, $$: unique on the host while the loop runs, so it is given unquoted)
    child = "env %s=$$ " % SESSION_MARK + " ".join(shlex.quote(a) for a in argv[1:])
    # The child runs in the background of a small POSIX sh watch loop: the parent writes a newline
    # every HEARTBEAT_S seconds through the session's pty. When none arrives for HEARTBEAT_TIMEOUT_S,
    # the link is cut (neither side's TCP notices for minutes) and the loop stops the nodes itself:
    # the child would try to report each step to the unreachable parent and hang there. (`timeout
    # --foreground`: in a pgrp of its own, head would be stopped by SIGTTIN reading the tty.) The same
    # when the pty hangs up (HUP: the launcher was killed) or sshd ends the session (TERM): the child
    # gets SIGHUP too and stops its nodes, but under load its own orderly stop can take longer than 5 s.
    # stop_nodes freezes the child (so that nothing is respawned), SIGINTs every process of its nodes,
    # SIGKILLs what is left after NODE_GRACE_S, then the child.
    # Which processes are the nodes' is known by the session's mark in their environment, which every
    # process the child starts inherits, and theirs in turn: a node's whole process group and session,
    # whether or not its leader still runs. (Each node leads a session of its own, so the child's
    # children name them only while their leaders live: a shell script's leader exits at SIGINT at
    # once, leaving its background jobs, which ignore SIGINT; and either child, ours at its parent's
    # silence or at SIGHUP, Debian's at SIGHUP, may have SIGINTed its nodes before the loop acts.)
    # The grace is waited for only while one of them handles SIGINT: one that ignores it (SIGINT's bit,
    # 0x2, in its status' SigIgn mask: a background job, our child's no-orphans guard) only waits for
    # SIGKILL. The scan of /proc runs only at the stop, never while the nodes run.
    # An orderly end is the heartbeat ORDERLY_END instead: the parent's `shutdown` call has stopped
    # the nodes. A child with a process left (ours: its no-orphans guard) gets ORDERLY_WAIT_S to end
    # by itself (ours does in ~20 ms); one with none (Debian's, which would take ~0.3 s more to exit) is
    # ended at once. Then stop_nodes all the same, for what the nodes left: Debian's child waits for
    # each node's leader only, so a shell script's background jobs outlive its orderly stop. (When
    # nothing is left, as under ours, that is three scans of /proc, a few ms.)
    script = ("marked() { for f in $(grep -lzxF %s=$$ /proc/[0-9]*/environ 2>/dev/null); do\n"
              "p=${f#/proc/}; p=${p%%/environ}; [ \"$p\" = \"$child\" ] || echo $p; done; }\n"
              "heeds_int() { while read k v; do [ \"$k\" = SigIgn: ] && case $v in *[2367abef]) return 1;; *) return 0;;\n"
              "esac; done < /proc/$1/status; return 1; } 2>/dev/null\n"
              "stopping() { for p in $(marked); do heeds_int $p && return 0; done; return 1; }\n"
              "stop_nodes() { kill -STOP $child 2>/dev/null; pids=$(marked); [ -z \"$pids\" ] || kill -INT $pids 2>/dev/null\n"
              "i=0; while [ $i -lt %d ] && stopping; do sleep 0.1; i=$((i+1)); done\n"
              "pids=$(marked); [ -z \"$pids\" ] || kill -KILL $pids 2>/dev/null; kill -KILL $child 2>/dev/null; exit 0; }\n"
              "%s & child=$!\n"
              "trap stop_nodes HUP TERM\n"
              "while kill -0 $child 2>/dev/null && beat=$(timeout --foreground %s head -c 1 2>/dev/null); do\n"
              "if [ \"$beat\" = %s ]; then pgrep -P $child >/dev/null || break; i=0\n"
              "while [ $i -lt %d ] && kill -0 $child 2>/dev/null; do sleep 0.01; i=$((i+1)); done; break; fi; done\n"
              "stop_nodes" % (SESSION_MARK, int(NODE_GRACE_S * 10), child, HEARTBEAT_TIMEOUT_S,
                              ORDERLY_END.decode()[0], int(ORDERLY_WAIT_S / 0.01)))
    return "sh -c %s" % shlex.quote(script)


def ssh_argv(machine: Machine, command: str, environ: Mapping[str, str]) -> list[str]:
    """The local command line that runs `command` on the machine."""
    argv = shlex.split(environ.get("LAUNCHER_SSH_COMMAND") or "ssh")
    argv += ["-tt", "-o", "BatchMode=yes", "-o", "ServerAliveInterval=%d" % SERVER_ALIVE_INTERVAL_S,
             "-o", "ServerAliveCountMax=%d" % SERVER_ALIVE_COUNT_MAX,
             # half the registration timeout: an unreachable host is reported as such, not as a late child
             "-o", "ConnectTimeout=%d" % max(1, int(machine.timeout / 2)), "-p", str(machine.ssh_port)]
    if environ.get("ROSLAUNCH_SSH_UNKNOWN") == "1":
        # as roslaunch: an unknown host is accepted (and remembered); a changed key is still refused
        argv += ["-o", "StrictHostKeyChecking=accept-new"]
    if machine.user:
        argv += ["-l", machine.user]
    return argv + ["--", machine.address, command]


def explain_failure(machine: Machine, output: str, status: int | None, program: str) -> str:
    """Why a child on `machine` ended before registering, from ssh's and the remote shell's words."""
    where = "%s%s:%s" % (machine.user + "@" if machine.user else "", machine.address, machine.ssh_port)
    text = output.strip()
    last = text.splitlines()[-1].strip() if text else ""
    if "REMOTE HOST IDENTIFICATION HAS CHANGED" in text:
        return ("the host key of [%s] has changed (it does not match known_hosts); if the machine was "
                "reinstalled, remove the old key with: ssh-keygen -R %s" % (where, machine.address))
    if "Host key verification failed" in text or "host key is known" in text:
        return ("%s is not in your SSH known_hosts file.\nPlease manually:\n  ssh %s%s%s\nthen try "
                "launching again.\nIf you wish to accept unknown hosts automatically, set the environment "
                "variable ROSLAUNCH_SSH_UNKNOWN=1"
                % (machine.address, "-p %s " % machine.ssh_port if machine.ssh_port != 22 else "",
                   machine.user + "@" if machine.user else "", machine.address))
    if "Permission denied" in text:
        return ("authentication to remote computer [%s] failed: the key was refused (%s).\nA common cause "
                "is a missing key in the remote authorized_keys file, or no key loaded in the agent"
                % (where, last))
    if "Connection refused" in text:
        return "network connection refused by [%s]" % where
    if re.search(r"timed out|No route to host|Network is unreachable|Could not resolve|Name or service", text):
        return "unable to reach [%s]: %s" % (where, last)
    if status == 127 or "No such file or directory" in text or "not found" in text:
        # (the program first: a shell's "ENV_LOADER: 5: exec: roslaunch: not found" names both)
        if re.search(r"%s'?: (not found|No such file)" % re.escape(program), text):
            return "[%s] is not installed on [%s] (or not on the PATH its env-loader sets): %s" % (
                program, machine.address, last)
        if machine.env_loader and machine.env_loader in text:
            return "env-loader [%s] not found on [%s] (%s)" % (machine.env_loader, machine.address, last)
    if status == SSH_FAILED:
        return "ssh to [%s] failed: %s" % (where, last or "exit status 255")
    return "the remote %s on [%s] exited (status %s)%s" % (program, machine.address, status,
                                                           ": " + last if last else "")
