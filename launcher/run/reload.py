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

Nodes of other machines are stopped and started through the calls the operator's
stop and start use (remote.parent); a change that needs what a child cannot do
(Debian's roslaunch child stops no single node) or a child this run does not have
(a new machine) is refused by name, and nothing changes.
"""

from __future__ import annotations

import time
from typing import Any

from launcher import compat
from launcher.compat import to_thread
from launcher.model.errors import LaunchError
from launcher.output import console
from launcher.plan.diff import Difference, difference, lines
from launcher.plan.command import node_command
from launcher.run.load import plan_again


class Reloader:
    """The reloads of one run (`launcher_reload` on its API server); one at a time."""

    def __init__(self, run: Any):
        self.run = run  # runtime.Run: its plan, master session, nodes, log, systemd notifier
        self._lock = compat.Lock()

    async def reload(self, given: list[str], dry_run: bool) -> dict:
        """{"ok": bool, "error": text, "warnings": [...], "difference": Difference.as_dict(), "lines": [...],
        "applied": bool}."""
        bad = [a for a in given if ":=" not in a or a.startswith(":=")]
        if bad:
            return {"ok": False, "error": "reload takes name:=value args only, not %s" % ", ".join(map(repr, bad))}
        async with self._lock:
            run = self.run
            if run.signals.event.is_set():
                return {"ok": False, "error": "the launch is stopping"}
            old = run.plan
            warnings: list[str] = []
            started = time.monotonic()
            try:
                new, diff = await to_thread(self._load, old, given, warnings.append)
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
            except LaunchError as e:  # (the master refused a parameter, or went away: said, as a launch says it)
                console.printerrlog("reload: %s" % e)
                return {**answer, "ok": False, "error": "the reload failed part way (see `launcher events`): %s" % e}
            finally:
                if notifier is not None:
                    notifier.reloaded()
            run.log.timing(started, "reload: applied")
            answer["applied"] = True
            return answer

    def _load(self, old: Any, given: list[str], warn: Any) -> tuple[Any, Difference]:
        """(In a worker thread.) The new plan and its difference to the old one; LaunchError for bad input,
        a node whose executable cannot be found, or whose command line cannot be made, included (a launch
        would start without it; a reload that would lose a node for a typo does not happen)."""
        new = plan_again(old, self.run.opts, given, warn)
        packages = new.packages
        remote = frozenset(n.full_name for n in old.config.nodes if old.remote(n)) | frozenset(
            n.full_name for n in new.config.nodes if new.remote(n))
        diff = difference(old.config, new.config, self._executables(old, packages, strict=False),
                          self._executables(new, packages, strict=True), remote)
        changed = {c.name for c in diff.start + diff.restart}
        for node in new.config.nodes:
            if node.full_name in changed and not new.remote(node):
                node_command(node, master_uri=new.master_uri, environ=new.environ, packages=packages)
        return new, diff

    @staticmethod
    def _executables(plan: Any, packages: Any, strict: bool) -> dict[str, str]:
        """Each local node's executable, looked up with one package index for both plans (so that only what
        the files say, or a package that now has another executable, makes a difference)."""
        out = {}
        for node in plan.config.nodes:
            if plan.remote(node):
                continue
            try:
                out[node.full_name] = packages.find_node(node.package, node.type)
            except LaunchError as e:
                if strict:
                    raise LaunchError("node [%s] (%s/%s): %s" % (node.full_name, node.package, node.type, e.message),
                                      node.filename or None, node.line or None) from None
        return out

    def _remote_refusals(self, old: Any, new: Any, diff: Difference) -> list[str]:
        """Why the difference cannot be applied to the nodes of other machines, each by name ([]: it can).
        They go through the same calls as the operator's stop and start (remote.parent); a node whose
        machine has no child in this run, one that moves between this machine and another, and one to stop
        under Debian's roslaunch child (which cannot stop one node) need the launch restarted."""
        was = {n.full_name: n for n in old.config.nodes if old.remote(n)}
        now = {n.full_name: n for n in new.config.nodes if new.remote(n)}
        if not was and not now:
            return []
        moved = ["node [%s] moves from %s to %s: the launch needs a full restart for this change"
                 % (c.name, "machine [%s]" % was[c.name].machine_name if c.name in was else "this machine",
                    "machine [%s]" % now[c.name].machine_name if c.name in now else "this machine")
                 for c in diff.restart if (c.name in was) != (c.name in now)]
        stop = [(c.name, was[c.name].machine_name) for c in diff.stop + diff.restart if c.name in was]
        start = [now[c.name] for c in diff.start + diff.restart if c.name in now]
        parent = self.run.nodes.remote
        if parent is None:
            return moved + ["node [%s]: machine [%s] has no child in this launch: the launch needs a full restart "
                            "for this change" % (n.full_name, n.machine_name) for n in start]
        return moved + parent.reload_refusals(stop, start, new.config.machines)

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
