"""A reload of a running launch (issue 23): its files read again inside it, the difference to what runs (`plan.diff`), and that difference applied: parameters, then stops, then starts.

The files are read in the launch's own environment (`$(env)`, `$(optenv)`, the
package path are the launch's, not the caller's), with the args it was started
with (those given replace theirs), off the loop (a big launch takes a while to
read; the nodes are supervised meanwhile). A load that fails changes nothing and
its error (file:line) is the answer. The same `Difference` is what a dry run
prints and what a reload applies:

1. parameters: the deleted ones, then the set ones, on the run's master;
2. the nodes: stops (removed and changed nodes together), then the changed
   ones start anew and the new ones start, in the launch's order; supervision
   changes apply where each node stands (services/nodeservice.py);
3. the events file's `reload` line (fleet.state.Fleet.reloaded).

Nodes of other machines are not changed by a reload yet: a difference that would
start, stop or restart one is refused by name, and nothing changes.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any

from launcher.model.errors import LaunchError
from launcher.output import console
from launcher.plan.diff import Difference, command_key, difference, lines
from launcher.process.command import node_command


class Reloader:
    """The reloads of one run (`launcher_reload` on its API server); one at a time."""

    def __init__(self, run: Any):
        self.run = run  # runtime.Run: its plan, master session, nodes, log, systemd notifier
        self._lock = asyncio.Lock()

    async def reload(self, given: list[str], dry_run: bool) -> dict:
        """{"ok": bool, "error": text, "warnings": [...], "difference": Difference.as_dict(), "lines": [...],
        "applied": bool}."""
        bad = [a for a in given if ":=" not in a or a.startswith(":=")]
        if bad:
            return {"ok": False, "error": "reload takes name:=value args only, not %s" % ", ".join(map(repr, bad))}
        async with self._lock:
            run = self.run
            old = run.plan
            warnings: list[str] = []
            started = time.monotonic()
            try:
                new, diff = await asyncio.to_thread(self._load, old, given, warnings.append)
            except LaunchError as e:
                return {"ok": False, "error": str(e), "warnings": warnings}
            answer = {"ok": True, "warnings": warnings, "difference": diff.as_dict(), "lines": list(lines(diff)),
                      "applied": False}
            refused = self._remote_refusals(old, new, diff)
            if refused:
                return {**answer, "ok": False, "error": "\n".join(refused)}
            run.log.timing(started, "reload: files read, %d change(s)%s" % (len(answer["lines"]),
                                                                           " (dry run)" if dry_run else ""))
            if dry_run:
                return answer
            notifier = run.notifier
            if notifier is not None:
                notifier.reloading()
            try:
                await self._apply(new, diff)
            finally:
                if notifier is not None:
                    notifier.reloaded()
            run.log.timing(started, "reload: applied")
            answer["applied"] = True
            return answer

    def _load(self, old: Any, given: list[str], warn: Any) -> tuple[Any, Difference]:
        """(In a worker thread.) The new plan and its difference to the old one; LaunchError for bad input,
        a node whose executable cannot be found included (a launch would start without it; a reload that
        would lose a node for a typo does not happen)."""
        new = old.again(self.run.opts, given, warn)
        old_commands = self._commands(old, new.packages, strict=False)
        new_commands = self._commands(new, new.packages, strict=True)
        return new, difference(old.config, new.config, old_commands, new_commands)

    @staticmethod
    def _commands(plan: Any, packages: Any, strict: bool) -> dict[str, tuple]:
        """Each local node's command as the difference compares it, worked out with one package index for
        both plans (so that only what the files say makes a difference)."""
        out = {}
        for node in plan.config.nodes:
            if plan.remote(node):
                continue
            try:
                command = node_command(node, master_uri=plan.master_uri, environ=plan.environ, packages=packages)
            except LaunchError:
                if strict:
                    raise
                continue
            out[node.full_name] = command_key(command)
        return out

    def _remote_refusals(self, old: Any, new: Any, diff: Difference) -> list[str]:
        """The nodes of other machines the difference would start, stop or restart, each by name."""
        remote = {n.full_name: n.machine_name for n in old.config.nodes if old.remote(n)}
        remote.update((n.full_name, n.machine_name) for n in new.config.nodes if new.remote(n))
        return ["node [%s] runs on machine [%s]: a reload cannot %s it (stop and start the launch, or change only "
                "this machine's nodes)" % (c.name, remote[c.name], verb)
                for verb, changes in (("stop", diff.stop), ("restart", diff.restart), ("start", diff.start))
                for c in changes if c.name in remote]

    async def _apply(self, new: Any, diff: Difference) -> None:
        run = self.run
        words = reload_words(diff)
        console.printlog("reload: %s" % words)
        params = run.master.params
        for key in diff.delete:
            await params.delete(key)
        for key, value in diff.set:
            await params.set(key, value)
        await run.nodes.reload(diff, new)
        run.plan = run.master.plan = new
        fleet = run.nodes.fleet
        if fleet is not None:
            fleet.reloaded(words, set=[k for k, _ in diff.set], deleted=list(diff.delete),
                           restarted=[c.name for c in diff.restart], started=[c.name for c in diff.start],
                           stopped=[c.name for c in diff.stop], supervised=[c.name for c in diff.supervise])


def reload_words(diff: Difference) -> str:
    """A reload in a few words: `3 parameter(s) set, 1 deleted; restarted /a; started /b` ('nothing changed')."""
    parts = []
    if diff.set or diff.delete:
        parts.append("%d parameter(s) set, %d deleted" % (len(diff.set), len(diff.delete)))
    for verb, changes in (("restarted", diff.restart), ("started", diff.start), ("stopped", diff.stop),
                          ("new supervision settings for", diff.supervise)):
        if changes:
            parts.append("%s %s" % (verb, ", ".join(c.name for c in changes)))
    return "; ".join(parts) or "nothing changed"
