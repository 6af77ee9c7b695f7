"""The ROS graph as the launch knows it from its master: the registered nodes (name -> URI), the topics someone
publishes and the services someone provides, and who is told of each change.

The one writer is the master's side: our own master's registry (`master.registry`) tells it of each change as
it happens; a master found running is asked by its watcher (`services.masterwatch`), the one place outside
`master/` that asks a master about registrations. Every reader (the fleet's registrations, readiness' wait_for,
through them hang, stall, systemd's READY=1 and the bound-node holds) listens here instead of asking the master.
"""

from __future__ import annotations

import sys
from typing import Callable, Iterable

from launcher.model.record import record

NODE, TOPIC, SERVICE = "node", "topic", "service"


@record
class GraphChange:
    """A node registered (`present`, at `uri`) or went; a topic got its first publisher or lost its last one;
    a service got a provider or lost it (`uri` is then "")."""

    kind: str  # NODE, TOPIC or SERVICE
    name: str
    present: bool
    uri: str = ""


class Graph:
    """What is registered with the run's master now; `listeners` are called with each GraphChange."""

    def __init__(self) -> None:
        self.nodes: dict[str, str] = {}  # node name -> its XML-RPC URI ("" when the master did not say)
        self.topics: set[str] = set()  # topics with a publisher
        self.services: set[str] = set()
        self.listeners: list[Callable[[GraphChange], None]] = []
        # the (kind, name) each reader waits for: a watcher of a master found running asks about these (our own
        # master tells everything anyway)
        self._wants: dict[int, set[tuple[str, str]]] = {}
        self.warn: Callable[[str], None] = lambda text: print(text, file=sys.stderr)

    def want(self, reader: object, conditions: set[tuple[str, str]]) -> None:
        """What `reader` waits for now (an empty set: nothing)."""
        if conditions:
            self._wants[id(reader)] = set(conditions)
        else:
            self._wants.pop(id(reader), None)

    @property
    def wanted(self) -> set[tuple[str, str]]:
        return set().union(*self._wants.values())

    def has(self, kind: str, name: str) -> bool:
        if kind == NODE:
            return name in self.nodes
        return name in (self.topics if kind == TOPIC else self.services)

    def node(self, name: str, uri: str | None) -> None:
        """`name` registered at `uri`, or (None) is known no more."""
        old = self.nodes.get(name)
        if uri is None:
            if old is not None:
                del self.nodes[name]
                self._tell(GraphChange(NODE, name, False, old))
        elif old != uri:
            self.nodes[name] = uri
            self._tell(GraphChange(NODE, name, True, uri))

    def key(self, kind: str, name: str, present: bool) -> None:
        """A topic (TOPIC) has a publisher or has none; a service (SERVICE) a provider or none."""
        keys = self.topics if kind == TOPIC else self.services
        if present != (name in keys):
            (keys.add if present else keys.discard)(name)
            self._tell(GraphChange(kind, name, present))

    def replace(self, nodes: dict[str, str] | None = None, topics: Iterable[str] | None = None,
                services: Iterable[str] | None = None) -> None:
        """A whole answer of a master (None: that part was not asked): the changes since the last one told."""
        if nodes is not None:
            for name in [n for n in self.nodes if n not in nodes]:
                self.node(name, None)
            for name, uri in nodes.items():
                self.node(name, uri)
        for kind, names, keys in ((TOPIC, topics, self.topics), (SERVICE, services, self.services)):
            if names is None:
                continue
            now = set(names)
            for name in sorted(keys - now):
                self.key(kind, name, False)
            for name in sorted(now - keys):
                self.key(kind, name, True)

    def clear(self) -> None:
        """The master restarted: nothing is registered with it any more."""
        self.replace({}, (), ())

    def _tell(self, change: GraphChange) -> None:
        for listener in list(self.listeners):
            try:
                listener(change)
            except Exception as e:  # noqa: BLE001 - a reader's bug must not fail the node's registration call
                self.warn("internal error in %r: %s: %s" % (listener, type(e).__name__, e))
