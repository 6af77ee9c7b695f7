"""The Master API and Parameter Server API: argument checks, name resolution and return triples.

Every method answers `(code, status message, value)` exactly as rosmaster's
`apivalidate` wrapper does: -1 and a method-specific value for a missing
caller_id, a bad arity or an invalid argument; 0 for an internal failure.
Callbacks to nodes are handed to the Notifier and never awaited here, so a
reply never waits for a node.
"""

from __future__ import annotations

import os
from typing import Any, Callable

import launcher.master.registry as reg
from launcher.master.masterlog import mlog  # master.log, in rosmaster's lines
from launcher.master.notify import Notifier, since_boot
from launcher.model.names import ANYTYPE, SEP, canonicalize_name, resolve_name
from launcher.params.tree import ParamTree, copy_tree
from launcher.net.xmlrpc_codec import Encoded, Fault, encode_value, unsendable


NO_CHECK = None  # an argument passed on as it is


class ParameterInvalid(Exception):
    """An argument rejected by a validator (answered with -1)."""


# ---------------------------------------------------------------------------
# validators: (value, caller_id) -> canonical value, or raise ParameterInvalid
# ---------------------------------------------------------------------------

def non_empty_str(pname: str) -> Callable[[Any, str], Any]:
    def v(value: Any, caller_id: str) -> Any:
        if not value:
            raise ParameterInvalid("ERROR: parameter [%s] must be specified and non-empty" % pname)
        if type(value) is not str:
            raise ParameterInvalid("ERROR: parameter [%s] must be a string" % pname)
        return value
    return v


def not_none(pname: str) -> Callable[[Any, str], Any]:
    def v(value: Any, caller_id: str) -> Any:
        if value is None:
            raise ParameterInvalid("ERROR: parameter [%s] must be specified" % pname)
        return value
    return v


def is_api(pname: str) -> Callable[[Any, str], Any]:
    def v(value: Any, caller_id: str) -> Any:
        if not value or type(value) is not str:
            raise ParameterInvalid("ERROR: parameter [%s] is not an XMLRPC URI" % pname)
        if not value.startswith("http://") and not value.startswith("rosrpc://"):
            raise ParameterInvalid("ERROR: parameter [%s] is not an RPC URI" % pname)
        return value
    return v


def valid_name(pname: str) -> Callable[[Any, str], Any]:
    def v(value: Any, caller_id: str) -> Any:
        if not value or type(value) is not str:
            raise ParameterInvalid("ERROR: parameter [%s] must be a non-empty string" % pname)
        if ":" in value or " " in value:
            raise ParameterInvalid("ERROR: parameter [%s] contains illegal chars" % pname)
        return resolve_name(value, caller_id)
    return v


def is_graph_resource(pname: str) -> Callable[[Any, str], Any]:
    """A topic or service name: a valid name that is not the root namespace."""
    base = valid_name(pname)

    def v(value: Any, caller_id: str) -> Any:
        resolved = base(value, caller_id)
        if value == SEP:
            raise ParameterInvalid("ERROR: parameter [%s] cannot be the global namespace" % pname)
        return resolved
    return v


def empty_or_valid_name(pname: str) -> Callable[[Any, str], Any]:
    def v(value: Any, caller_id: str) -> Any:
        if type(value) is not str:
            raise ParameterInvalid("ERROR: parameter [%s] must be a string" % pname)
        if not value:
            return ""
        return resolve_name(value, caller_id)
    return v


def valid_type_name(pname: str) -> Callable[[Any, str], Any]:
    def v(value: Any, caller_id: str) -> Any:
        if value == ANYTYPE:
            return value
        if not value or type(value) is not str:
            raise ParameterInvalid("ERROR: parameter [%s] must be a non-empty string" % pname)
        if len(value.split(SEP)) != 2:
            raise ParameterInvalid("ERROR: parameter [%s] is not a valid package resource name" % pname)
        return value
    return v


# ---------------------------------------------------------------------------
# parameter subscriptions: who hears about a change (rosmaster's compute_param_updates)
# ---------------------------------------------------------------------------

def _all_keys(prefix: str, value: dict, out: list[str]) -> list[str]:
    for k, v in value.items():
        key = (k if k[:1] in ("/", "~") else prefix + k) + SEP
        out.append(key)
        if type(v) is dict:
            _all_keys(key, v, out)
    return out


def param_updates(subscribers: reg.Registrations, key: str, value: Any, ignore_caller: str | None = None
                  ) -> list[tuple[list[tuple[str, str]], str, Any, str]]:
    """[(subscribers, key sent, value sent, subscribed key)] for a set (or, with value {}, a delete)."""
    if not subscribers.map:
        return []
    if key != SEP:
        key = canonicalize_name(key) + SEP
    all_keys = _all_keys(key, value, []) if type(value) is dict else None
    updates = []
    for sub_key, node_apis in subscribers.map.items():
        ns_key = sub_key if sub_key[-1] == SEP else sub_key + SEP
        if key.startswith(ns_key):
            if ignore_caller is not None:
                # the setter is not told about its own change (deletes are always told)
                node_apis = [n for n in node_apis if n[0] != ignore_caller]
            updates.append((list(node_apis), key, value, sub_key))
        elif all_keys is not None and ns_key.startswith(key) and sub_key not in all_keys:
            updates.append((list(node_apis), sub_key, {}, sub_key))
    if all_keys is not None:
        for k in all_keys:
            if k in subscribers.map:
                v = value
                for part in k[len(key):].split(SEP):
                    if part:
                        v = v[part]
                updates.append((list(subscribers.map[k]), k, v, k))
    return updates


# ---------------------------------------------------------------------------
# the handler
# ---------------------------------------------------------------------------

class MasterApi:
    """Method table and state of one master. `dispatch(method, params)` answers a call."""

    def __init__(self, notifier: Notifier, params: ParamTree | None = None, uri: str = "", graph: Any = None):
        self.uri = uri
        self.notifier = notifier
        self.params = params if params is not None else ParamTree()
        # graph: a model.graph.Graph told of every registration's coming and going (the launch's readers)
        self.registry = reg.Registry(self._bumped, notifier.forget, since_boot, graph)
        self.topic_types: dict[str, str] = {}
        self._names_cache: tuple[int, int, Encoded] | None = None  # (tree id, shape_version, names)
        self.on_shutdown: Callable[[str], None] | None = None
        self.pid = os.getpid()
        # method -> (function, number of XML-RPC args incl. caller_id, error value, validators)
        self.methods: dict[str, tuple[Callable, int, Any, tuple]] = {}
        for name, errval, validators in (
            ("shutdown", 0, (NO_CHECK,)),
            ("getUri", "", ()),
            ("getPid", -1, ()),
            ("deleteParam", 0, (non_empty_str("key"),)),
            ("setParam", 0, (non_empty_str("key"), not_none("value"))),
            ("getParam", 0, (non_empty_str("key"),)),
            ("searchParam", 0, (non_empty_str("key"),)),
            ("subscribeParam", 0, (is_api("caller_api"), non_empty_str("key"))),
            ("unsubscribeParam", 0, (is_api("caller_api"), non_empty_str("key"))),
            ("hasParam", False, (non_empty_str("key"),)),
            ("getParamNames", [], ()),
            ("registerService", 0, (is_graph_resource("service"), is_api("service_api"), is_api("caller_api"))),
            ("lookupService", "", (is_graph_resource("service"),)),
            ("unregisterService", 0, (is_graph_resource("service"), is_api("service_api"))),
            ("registerSubscriber", [], (is_graph_resource("topic"), valid_type_name("topic_type"), is_api("caller_api"))),
            ("unregisterSubscriber", 0, (is_graph_resource("topic"), is_api("caller_api"))),
            ("registerPublisher", [], (is_graph_resource("topic"), valid_type_name("topic_type"), is_api("caller_api"))),
            ("unregisterPublisher", 0, (is_graph_resource("topic"), is_api("caller_api"))),
            ("lookupNode", "", (valid_name("node"),)),
            ("getPublishedTopics", 0, (empty_or_valid_name("subgraph"),)),
            ("getTopicTypes", [], ()),
            ("getSystemState", [[], [], []], ()),
        ):
            self.methods[name] = (getattr(self, name), len(validators) + 1, errval, validators)

    # -- dispatch -------------------------------------------------------------------
    def dispatch(self, method: str, params: list) -> Any:
        entry = self.methods.get(method)
        if entry is None:
            raise Fault(1, "<class 'Exception'>:method \"%s\" is not supported" % method)
        func, nargs, errval, validators = entry
        n = len(params)
        if n == 0:
            return (-1, "missing required caller_id parameter", errval)
        if n != nargs:
            return (-1, "Error: bad call arity", errval)
        caller_id = params[0]
        if type(caller_id) is not str:
            return (-1, "caller_id must be a string", errval)
        try:
            if validators:
                args = []
                for v, a in zip(validators, params[1:]):
                    if v is None:
                        args.append(a)
                    else:
                        try:
                            args.append(v(a, caller_id))
                        except ParameterInvalid as e:
                            return (-1, str(e) or "error", errval)
                code, msg, val = func(caller_id, *args)
            else:
                code, msg, val = func(caller_id)
        except TypeError as e:
            return (-1, "Error: invalid arguments: %s" % e, errval)
        except Exception as e:  # noqa: BLE001 - rosmaster answers any other failure with code 0
            return (0, "Internal failure: %s" % e, errval)
        if val is None:
            return (-1, "Internal error (None value returned)", errval)
        return (code, msg, val)

    # -- callbacks ------------------------------------------------------------------
    def _bumped(self, old: reg.NodeRef, caller_id: str) -> None:
        # rosmaster tells the old URI to shut down blindly: if that port is now another process's, the wrong
        # node dies (ros/ros_comm#2241, #2018). Only the process that registered there is told (notify.py).
        self.notifier.shutdown_node(old.api, caller_id, "new node registered with same name", old.registered_at)

    def _notify_params(self, updates: list) -> None:
        for subscribers, key, value, sub_key in updates:
            if type(value) is dict:
                value = copy_tree(value)  # later sets below it must not change what is sent
            for caller_id, caller_api in subscribers:
                self.notifier.param_update(caller_api, key, value,
                                           self._param_update_result(caller_id, caller_api, sub_key))

    def _param_update_result(self, caller_id: str, caller_api: str, sub_key: str) -> Callable[[Any], None]:
        def on_result(result: Any) -> None:
            # a node answering -1 does not want this parameter any more: drop the subscription
            # (rosmaster means to, but fails internally and keeps it forever)
            if isinstance(result, list) and result and result[0] == -1:
                node = self.registry.get_node(caller_id)
                if node is not None and node.api == caller_api:
                    self.registry.unregister(reg.PARAM_SUBSCRIPTIONS, sub_key, caller_id, caller_api)
        return on_result

    def _notify_topic(self, topic: str) -> None:
        sub_apis = self.registry.subscribers.get_apis(topic)
        if sub_apis:
            pub_uris = self.registry.publishers.get_apis(topic)
            for api in sub_apis:
                self.notifier.publisher_update(api, topic, pub_uris)

    # -- in-process parameter access (with notifications) ----------------------------
    def set_param(self, key: str, value: Any, caller_id: str | None = None) -> None:
        self.params.set(key, value)
        subs = self.registry.param_subscribers
        if subs.map:
            self._notify_params(param_updates(subs, key, value, caller_id))

    def delete_param(self, key: str) -> None:
        self.params.delete(key)
        subs = self.registry.param_subscribers
        if subs.map:
            self._notify_params(param_updates(subs, key, {}))

    # -- Master API -------------------------------------------------------------------
    def shutdown(self, caller_id: str, msg: Any) -> tuple:
        if self.on_shutdown is not None:
            self.on_shutdown(str(msg))  # rosmaster prints "shutdown request: <msg>"
        return 1, "shutdown", 0

    def getUri(self, caller_id: str) -> tuple:  # noqa: N802 - XML-RPC method names
        return 1, "", self.uri

    def getPid(self, caller_id: str) -> tuple:  # noqa: N802
        return 1, "", self.pid

    def deleteParam(self, caller_id: str, key: str) -> tuple:  # noqa: N802
        key = resolve_name(key, caller_id)
        try:
            self.delete_param(key)
        except KeyError:
            return -1, "parameter [%s] is not set" % key, 0
        mlog.info("-PARAM [%s] by %s", key, caller_id)
        return 1, "parameter %s deleted" % key, 0

    def setParam(self, caller_id: str, key: str, value: Any) -> tuple:  # noqa: N802
        key = resolve_name(key, caller_id)
        problem = unsendable(value)
        if problem:
            # stored, it would break every later getParam of it or of a namespace above it, '/'
            # included, for every client (rosmaster has this flaw)
            return -1, "parameter [%s] is not set: %s" % (key, problem), 0
        self.set_param(key, value, caller_id)
        mlog.info("+PARAM [%s] by %s", key, caller_id)
        return 1, "parameter %s set" % key, 0

    def getParam(self, caller_id: str, key: str) -> tuple:  # noqa: N802
        key = resolve_name(key, caller_id)
        try:
            return 1, "Parameter [%s]" % key, self.params.get(key)
        except KeyError:
            return -1, "Parameter [%s] is not set" % key, 0

    def searchParam(self, caller_id: str, key: str) -> tuple:  # noqa: N802
        found = self.params.search(caller_id, key)
        if found:
            return 1, "Found [%s]" % found, found
        return -1, "Cannot find parameter [%s] in an upwards search" % key, ""

    def subscribeParam(self, caller_id: str, caller_api: str, key: str) -> tuple:  # noqa: N802
        key = resolve_name(key, caller_id)
        sub_key = key if key == SEP else canonicalize_name(key) + SEP
        try:
            val = self.params.get(sub_key)
        except KeyError:
            val = {}
        self.registry.register(reg.PARAM_SUBSCRIPTIONS, sub_key, caller_id, caller_api)
        mlog.info("+CACHEDPARAM [%s] by %s", key, caller_id)
        return 1, "Subscribed to parameter [%s]" % key, val

    def unsubscribeParam(self, caller_id: str, caller_api: str, key: str) -> tuple:  # noqa: N802
        key = resolve_name(key, caller_id)
        sub_key = key if key == SEP else canonicalize_name(key) + SEP
        self.registry.unregister(reg.PARAM_SUBSCRIPTIONS, sub_key, caller_id, caller_api)
        mlog.info("-CACHEDPARAM [%s] by %s", key, caller_id)
        return 1, "Unsubscribe to parameter [%s]" % key, 1

    def hasParam(self, caller_id: str, key: str) -> tuple:  # noqa: N802
        key = resolve_name(key, caller_id)
        return 1, key, self.params.has(key)

    def getParamNames(self, caller_id: str) -> tuple:  # noqa: N802
        tree = self.params
        cache = self._names_cache
        if cache is None or cache[0] != id(tree.root) or cache[1] != tree.shape_version:
            cache = self._names_cache = (id(tree.root), tree.shape_version, encode_value(tree.names()))
        return 1, "Parameter names", cache[2]

    def registerService(self, caller_id: str, service: str, service_api: str, caller_api: str) -> tuple:  # noqa: N802
        self.registry.register(reg.SERVICES, service, caller_id, caller_api, service_api)
        mlog.info("+SERVICE [%s] %s %s", service, caller_id, caller_api)
        return 1, "Registered [%s] as provider of [%s]" % (caller_id, service), 1

    def lookupService(self, caller_id: str, service: str) -> tuple:  # noqa: N802
        url = self.registry.services.get_service_api(service)
        if url:
            return 1, "rosrpc URI: [%s]" % url, url
        return -1, "no provider", ""

    def unregisterService(self, caller_id: str, service: str, service_api: str) -> tuple:  # noqa: N802
        ret = self.registry.unregister(reg.SERVICES, service, caller_id, None, service_api)
        mlog.info("-SERVICE [%s] %s %s", service, caller_id, service_api)
        return ret

    def registerSubscriber(self, caller_id: str, topic: str, topic_type: str, caller_api: str) -> tuple:  # noqa: N802
        self.registry.register(reg.SUBSCRIPTIONS, topic, caller_id, caller_api)
        mlog.info("+SUB [%s] %s %s", topic, caller_id, caller_api)
        if topic_type != ANYTYPE and topic not in self.topic_types:
            self.topic_types[topic] = topic_type
        return 1, "Subscribed to [%s]" % topic, self.registry.publishers.get_apis(topic)

    def unregisterSubscriber(self, caller_id: str, topic: str, caller_api: str) -> tuple:  # noqa: N802
        ret = self.registry.unregister(reg.SUBSCRIPTIONS, topic, caller_id, caller_api)
        mlog.info("-SUB [%s] %s %s", topic, caller_id, caller_api)
        return ret

    def registerPublisher(self, caller_id: str, topic: str, topic_type: str, caller_api: str) -> tuple:  # noqa: N802
        self.registry.register(reg.PUBLICATIONS, topic, caller_id, caller_api)
        mlog.info("+PUB [%s] %s %s", topic, caller_id, caller_api)
        if topic_type != ANYTYPE or topic not in self.topic_types:
            self.topic_types[topic] = topic_type
        self._notify_topic(topic)
        return 1, "Registered [%s] as publisher of [%s]" % (caller_id, topic), self.registry.subscribers.get_apis(topic)

    def unregisterPublisher(self, caller_id: str, topic: str, caller_api: str) -> tuple:  # noqa: N802
        ret = self.registry.unregister(reg.PUBLICATIONS, topic, caller_id, caller_api)
        mlog.info("-PUB [%s] %s %s", topic, caller_id, caller_api)
        if ret[2]:
            self._notify_topic(topic)
        return ret

    def unregister_process(self, caller_id: str, caller_api: str) -> int:
        """Everything `caller_id` registered under `caller_api` (a process that ended) goes, as if it had
        unregistered it all itself: subscribers of its topics are told. The number of registrations removed."""
        node = self.registry.get_node(caller_id)
        if node is None or node.api != caller_api:
            return 0  # (gone already, or a new run of that name has registered since)
        keys = {kind: sorted(node.keys[kind]) for kind in node.keys}
        for topic in keys[reg.PUBLICATIONS]:
            self.unregisterPublisher(caller_id, topic, caller_api)
        for topic in keys[reg.SUBSCRIPTIONS]:
            self.unregisterSubscriber(caller_id, topic, caller_api)
        for service in keys[reg.SERVICES]:
            api = self.registry.services.service_api_map.get(service, (None, None))[1]
            self.unregisterService(caller_id, service, api)
        for sub_key in keys[reg.PARAM_SUBSCRIPTIONS]:
            self.registry.unregister(reg.PARAM_SUBSCRIPTIONS, sub_key, caller_id, caller_api)
        return sum(len(v) for v in keys.values())

    def lookupNode(self, caller_id: str, node_name: str) -> tuple:  # noqa: N802
        node = self.registry.get_node(node_name)
        if node is not None:
            return 1, "node api", node.api
        return -1, "unknown node [%s]" % node_name, ""

    def getPublishedTopics(self, caller_id: str, subgraph: str) -> tuple:  # noqa: N802
        if subgraph and subgraph[-1] != SEP:
            subgraph += SEP
        types = self.topic_types
        return 1, "current topics", [[t, types[t]] for t in self.registry.publishers.map if t.startswith(subgraph)]

    def getTopicTypes(self, caller_id: str) -> tuple:  # noqa: N802
        return 1, "current system state", [[t, ty] for t, ty in self.topic_types.items()]

    def getSystemState(self, caller_id: str) -> tuple:  # noqa: N802
        r = self.registry
        return 1, "current system state", [r.publishers.get_state_encoded(), r.subscribers.get_state_encoded(),
                                           r.services.get_state_encoded()]
