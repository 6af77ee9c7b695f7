"""The graph registry: who publishes, subscribes, provides services and watches parameters.

Mirrors rosmaster's RegistrationManager so that every observable detail
matches: registration order (getSystemState, publisher lists), one provider
per service, a node known while it has any registration, and a node name
re-registered with a new API bumping the old one.
"""

from __future__ import annotations

from typing import Callable

from launcher.net.xmlrpc_codec import Encoded, encode_value

PUBLICATIONS = 1
SUBSCRIPTIONS = 2
SERVICES = 3
PARAM_SUBSCRIPTIONS = 4


class NodeRef:
    """A known node: its API, when it first registered there and what it registered (the node is forgotten
    when all are gone)."""

    __slots__ = ("id", "api", "keys", "registered_at")

    def __init__(self, node_id: str, api: str, registered_at: float = 0.0):
        self.id = node_id
        self.api = api
        # since boot (CLOCK_BOOTTIME, as /proc gives a process's start): a process that answers at `api` and
        # started later is not this node (notify.Notifier.shutdown_node)
        self.registered_at = registered_at
        self.keys: dict[int, set[str]] = {PUBLICATIONS: set(), SUBSCRIPTIONS: set(), SERVICES: set(),
                                          PARAM_SUBSCRIPTIONS: set()}

    def is_empty(self) -> bool:
        k = self.keys
        return not (k[PUBLICATIONS] or k[SUBSCRIPTIONS] or k[SERVICES] or k[PARAM_SUBSCRIPTIONS])


class Registrations:
    """key (topic, service or parameter key) -> [(caller_id, caller_api)] in registration order."""

    __slots__ = ("kind", "map", "service_api_map", "_frags", "_state", "_had_services", "on_key")

    def __init__(self, kind: int):
        self.kind = kind
        self.map: dict[str, list[tuple[str, str]]] = {}
        self.service_api_map: dict[str, tuple[str, str]] = {}
        # encoded getSystemState pieces, per key and whole (dropped when a key changes)
        self._frags: dict[str, str] = {}
        self._state: Encoded | None = None
        self._had_services = False  # rosmaster's wording differs until a first service registers
        # told (key, present) when a key gets its first registration or loses its last (model.graph)
        self.on_key: Callable[[str, bool], None] | None = None

    def _changed(self, key: str) -> None:
        self._frags.pop(key, None)
        self._state = None

    def __contains__(self, key: str) -> bool:
        return key in self.map

    def __getitem__(self, key: str) -> list[tuple[str, str]]:
        return self.map.get(key, [])

    def get_apis(self, key: str) -> list[str]:
        return [api for _, api in self.map.get(key, ())]

    def get_service_api(self, service: str) -> str | None:
        entry = self.service_api_map.get(service)
        return entry[1] if entry else None

    def get_state(self) -> list[list]:
        return [[key, [node for node, _ in providers]] for key, providers in self.map.items()]

    def get_state_encoded(self) -> Encoded:
        """get_state() as an XML-RPC array, rebuilt only for the keys that changed."""
        state = self._state
        if state is None:
            frags = self._frags
            parts = ["<value><array><data>"]
            for key, providers in self.map.items():
                frag = frags.get(key)
                if frag is None:
                    frag = frags[key] = encode_value([key, [node for node, _ in providers]])
                parts.append(frag)
            parts.append("</data></array></value>")
            state = self._state = Encoded("".join(parts))
        return state

    def register(self, key: str, caller_id: str, caller_api: str, service_api: str | None = None) -> None:
        if service_api:
            # a service has exactly one provider: the newest registration wins
            new = key not in self.map
            self.map[key] = [(caller_id, caller_api)]
            self.service_api_map[key] = (caller_id, service_api)
            self._had_services = True
            self._changed(key)
            if new and self.on_key is not None:
                self.on_key(key, True)
            return
        providers = self.map.get(key)
        if providers is None:
            self.map[key] = [(caller_id, caller_api)]
            self._changed(key)
            if self.on_key is not None:
                self.on_key(key, True)
        elif (caller_id, caller_api) not in providers:
            providers.append((caller_id, caller_api))
            self._changed(key)

    def unregister(self, key: str, caller_id: str, caller_api: str | None,
                   service_api: str | None = None) -> tuple[int, str, int]:
        if service_api:
            if not self.service_api_map and not self._had_services:
                return 1, "[%s] is not a provider of [%s]" % (caller_id, key), 0
            if self.service_api_map.get(key) != (caller_id, service_api):
                return 1, "[%s] is no longer the current service api handle for [%s]" % (service_api, key), 0
            del self.service_api_map[key]
            del self.map[key]
            self._changed(key)
            if self.on_key is not None:
                self.on_key(key, False)
            return 1, "Unregistered [%s] as provider of [%s]" % (caller_id, key), 1
        providers = self.map.get(key)
        entry = (caller_id, caller_api)
        if providers is not None and entry in providers:
            providers.remove(entry)
            if not providers:
                del self.map[key]
                if self.on_key is not None:
                    self.on_key(key, False)
            self._changed(key)
            return 1, "Unregistered [%s] as provider of [%s]" % (caller_id, key), 1
        return 1, "[%s] is not a known provider of [%s]" % (caller_id, key), 0

    def unregister_all(self, caller_id: str) -> None:
        """Drop every registration of `caller_id` (no notifications: the node was replaced)."""
        dead = []
        for key, providers in self.map.items():
            kept = [p for p in providers if p[0] != caller_id]
            if len(kept) != len(providers):
                providers[:] = kept
                self._changed(key)
                if not providers:
                    dead.append(key)
        for key in dead:
            del self.map[key]
            if self.on_key is not None:
                self.on_key(key, False)
        for key in [k for k, v in self.service_api_map.items() if v[0] == caller_id]:
            del self.service_api_map[key]


class Registry:
    """All registrations plus the node table.

    `on_bump(old_node, caller_id)` is called when a node name registers with a
    new API: the master tells the old process to shut down. `on_gone(api)` is
    called when no node is known by `api` any more: nothing is owed to it.
    `clock()` says when (since boot) a name registers with an API it did not have. `graph` (a
    model.graph.Graph) is told each node that registers or goes, each topic that gets its first publisher
    or loses its last, each service that gets or loses its provider.
    """

    def __init__(self, on_bump, on_gone=None, clock=lambda: 0.0, graph=None):
        self.nodes: dict[str, NodeRef] = {}
        self._api_users: dict[str, int] = {}  # api -> known nodes with it (a client may reuse one for many)
        self.publishers = Registrations(PUBLICATIONS)
        self.subscribers = Registrations(SUBSCRIPTIONS)
        self.services = Registrations(SERVICES)
        self.param_subscribers = Registrations(PARAM_SUBSCRIPTIONS)
        self._by_kind = {PUBLICATIONS: self.publishers, SUBSCRIPTIONS: self.subscribers,
                         SERVICES: self.services, PARAM_SUBSCRIPTIONS: self.param_subscribers}
        self._on_bump = on_bump
        self._on_gone = on_gone
        self._clock = clock
        self._graph = graph
        if graph is not None:
            self.publishers.on_key = lambda key, present: graph.key("topic", key, present)
            self.services.on_key = lambda key, present: graph.key("service", key, present)

    def get_node(self, caller_id: str) -> NodeRef | None:
        return self.nodes.get(caller_id)

    def _node_for(self, caller_id: str, caller_api: str) -> NodeRef:
        node = self.nodes.get(caller_id)
        if node is not None and node.api == caller_api:
            return node
        fresh = NodeRef(caller_id, caller_api, self._clock())
        self.nodes[caller_id] = fresh
        self._api_users[caller_api] = self._api_users.get(caller_api, 0) + 1
        if node is not None:
            # same name, new process: the old one is told to go and forgotten entirely
            self._on_bump(node, caller_id)
            for r in self._by_kind.values():
                r.unregister_all(caller_id)
            self._released(node.api)
        if self._graph is not None:
            self._graph.node(caller_id, caller_api)
        return fresh

    def _released(self, api: str) -> None:
        left = self._api_users[api] - 1
        if left:
            self._api_users[api] = left
            return
        del self._api_users[api]
        if self._on_gone is not None:
            self._on_gone(api)

    def register(self, kind: int, key: str, caller_id: str, caller_api: str,
                 service_api: str | None = None) -> None:
        node = self._node_for(caller_id, caller_api)
        node.keys[kind].add(key)
        self._by_kind[kind].register(key, caller_id, caller_api, service_api)

    def unregister(self, kind: int, key: str, caller_id: str, caller_api: str | None,
                   service_api: str | None = None) -> tuple[int, str, int]:
        node = self.nodes.get(caller_id)
        if node is None:
            return 1, "[%s] is not a registered node" % caller_id, 0
        ret = self._by_kind[kind].unregister(key, caller_id, caller_api, service_api)
        if ret[2] == 1:
            node.keys[kind].discard(key)
        if node.is_empty():
            del self.nodes[caller_id]
            self._released(node.api)
            if self._graph is not None:
                self._graph.node(caller_id, None)
        return ret
