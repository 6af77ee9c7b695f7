"""MasterApi against rosmaster's own ROSMasterHandler: same random calls, same replies, same callbacks.

The reference handler (Debian's python3-rosmaster) runs in a subprocess with
its thread pool replaced by a recorder, so the callbacks it would send are
compared too, in order. Skipped where rosmaster is not installed.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import xmlrpc.client


from launcher.master.api import MasterApi
from launcher.net.xmlrpc_codec import dumps_response

REFERENCE = r'''
import copy, json, sys, xmlrpc.client
import rosmaster.master_api as ma

class Recorder:
    def __init__(self): self.calls = []
    def queue_task(self, mark, task, args):
        name = getattr(task, "__name__", str(task))
        if name == "publisher_update_task":
            api, topic, uris = args; self.calls.append(["publisherUpdate", api, topic, list(uris)])
        elif name == "param_update_task":
            caller_id, api, key, value = args
            # copied now: the reference queues the tree's own dict, which later sets mutate
            self.calls.append(["paramUpdate", api, key, copy.deepcopy(value)])
        elif name == "shutdown_node_task":
            api, caller_id, reason = args
            self.calls.append(["shutdown", api, "[%s] Reason: %s" % (caller_id, reason)])
        else:
            self.calls.append(["?", name])
    def join_all(self, *a, **k): pass

out = []
for seq in json.load(sys.stdin):
    h = ma.ROSMasterHandler(num_workers=1)
    h.thread_pool.join_all(wait_for_tasks=False, wait_for_threads=False)
    rec = Recorder()
    h.thread_pool = rec
    h.reg_manager.thread_pool = rec
    h._ready("http://master:11311/")
    res = []
    for method, params in seq:
        rec.calls = []
        try:
            r = getattr(h, method)(*params)
            r = xmlrpc.client.loads(xmlrpc.client.dumps((r,), methodresponse=True))[0][0]
        except Exception as e:
            r = ["exception", type(e).__name__]
        res.append([r, rec.calls])
    out.append(res)
json.dump(out, sys.stdout)
'''


class RecordingNotifier:
    def __init__(self):
        self.calls = []

    def publisher_update(self, api, topic, pub_uris):
        self.calls.append(["publisherUpdate", api, topic, list(pub_uris)])

    def param_update(self, api, key, value, on_result=None):
        self.calls.append(["paramUpdate", api, key, value])

    def shutdown_node(self, api, caller_id, reason, registered_at=None):
        self.calls.append(["shutdown", api, "[%s] Reason: %s" % (caller_id, reason)])

    def forget(self, api):
        pass  # ours alone: queued callbacks to a node no longer registered are dropped (no rosmaster call)


CALLERS = ["/n1", "/ns/n2", "/ns/sub/n3", "/n4", "", "rel", 7]
APIS = ["http://h:1/", "http://h:2/", "rosrpc://h:3", "bad", ""]
NAMES = ["t", "/t", "~t", "ns/t", "/ns/t", "/ns/sub/t", "", "/", "a b", "x:y", "t/"]
TYPES = ["std_msgs/String", "*", "pkg/Other", "bad", ""]
KEYS = ["p", "/p", "~p", "/ns/p", "ns/q", "/ns", "/", "", "/ns/sub/deep", "p/"]


def _value(rng, depth=0):
    r = rng.random()
    if depth < 2 and r < 0.3:
        return {rng.choice(["p", "q", "sub", "deep"]): _value(rng, depth + 1) for _ in range(rng.randint(0, 3))}
    if r < 0.4:
        return [1, "x"]
    if r < 0.8:
        return rng.randint(-3, 3)
    return rng.choice(["s", "", True])


def _call(rng):
    caller = rng.choice(CALLERS)
    api = rng.choice(APIS)
    m = rng.choice([
        "registerPublisher", "registerPublisher", "registerSubscriber", "registerSubscriber",
        "unregisterPublisher", "unregisterSubscriber", "registerService", "unregisterService",
        "lookupNode", "lookupService", "getPublishedTopics", "getTopicTypes", "getSystemState",
        "setParam", "setParam", "getParam", "deleteParam", "hasParam", "searchParam",
        "subscribeParam", "subscribeParam", "unsubscribeParam", "getParamNames", "getUri", "getPid"])
    if m in ("registerPublisher", "registerSubscriber"):
        params = [caller, rng.choice(NAMES), rng.choice(TYPES), api]
    elif m in ("unregisterPublisher", "unregisterSubscriber"):
        params = [caller, rng.choice(NAMES), api]
    elif m == "registerService":
        params = [caller, rng.choice(NAMES), rng.choice(["rosrpc://h:9", "rosrpc://h:8", "bad"]), api]
    elif m == "unregisterService":
        params = [caller, rng.choice(NAMES), rng.choice(["rosrpc://h:9", "rosrpc://h:8"])]
    elif m in ("lookupNode", "lookupService"):
        params = [caller, rng.choice(NAMES + ["n1", "/n1", "/ns/n2", "n2"])]
    elif m == "getPublishedTopics":
        params = [caller, rng.choice(["", "/", "ns", "/ns", "/ns/"])]
    elif m == "setParam":
        params = [caller, rng.choice(KEYS), _value(rng)]
    elif m in ("getParam", "deleteParam", "hasParam", "searchParam"):
        params = [caller, rng.choice(KEYS)]
    elif m in ("subscribeParam", "unsubscribeParam"):
        params = [caller, api, rng.choice(KEYS)]
    else:
        params = [caller]
    if rng.random() < 0.03:
        params = params[:-1]  # arity errors
    return m, params


def _ours(seq):
    notifier = RecordingNotifier()
    api = MasterApi(notifier, uri="http://master:11311/")
    res = []
    for method, params in seq:
        notifier.calls = []
        r = api.dispatch(method, list(json.loads(json.dumps(params))))
        r = xmlrpc.client.loads(dumps_response(r))[0][0]
        if method == "getPid" and r[0] == 1:
            assert r[2] == os.getpid()
            r[2] = "pid"
        res.append([r, notifier.calls])
    return json.loads(json.dumps(res))


def test_same_replies_and_callbacks_as_rosmaster(ros_env, ros_part_missing):
    py = ros_env["python"]
    if not os.path.exists(py) or subprocess.run([py, "-c", "import rosmaster.master_api"],
                                                capture_output=True).returncode != 0:
        ros_part_missing("rosmaster (Debian's python3-rosmaster) not importable")
    rng = random.Random(3)
    seqs = [[_call(rng) for _ in range(rng.randint(5, 60))] for _ in range(300)]
    proc = subprocess.run([py, "-c", REFERENCE], input=json.dumps(seqs), capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=""), timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    expected = json.loads(proc.stdout)
    for seq, want in zip(seqs, expected):
        for (method, _), step in zip(seq, want):
            if method == "getPid" and step[0][0] == 1:
                step[0][2] = "pid"

        got = _ours(seq)
        for i, (g, w) in enumerate(zip(got, want)):
            if seq[i][0] == "deleteParam" and w[0][1].startswith("Error: invalid arguments"):
                # deliberate difference: deleting below a scalar trips rosmaster over `key in <scalar>`;
                # we answer that the parameter is not set (same code, same value, same callbacks)
                assert (g[0][0], g[0][2], g[1]) == (w[0][0], w[0][2], w[1])
                assert g[0][1].endswith("is not set")
                continue
            assert g == w, "call %d %r of %r" % (i, seq[i], seq[:i + 1])
