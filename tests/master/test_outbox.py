"""The Outbox's decisions (order, coalescing, slots, the failing nodes' lane, back-off, forget) on a fake clock."""

from __future__ import annotations

from launcher.master.outbox import Callback, Outbox


def pub(topic, uris):
    return Callback("publisherUpdate", ["/master", topic, uris], key=("publisherUpdate", topic))


def param(key, value):
    return Callback("paramUpdate", ["/master", key, value], key=("paramUpdate", key))


def sent(pairs):
    return [(api, cb.method, cb.params[1:]) for api, cb in pairs]


def test_one_call_per_node_in_order_and_a_queued_publisher_list_is_replaced_in_its_place():
    o = Outbox()
    o.put("a", pub("/t", ["p1"]))
    o.put("a", param("/k/", 1))
    o.put("a", pub("/t", ["p1", "p2"]))  # replaces the queued one, which keeps its turn
    first = o.take(0.0, 10)
    assert sent(first) == [("a", "publisherUpdate", ["/t", ["p1", "p2"]])]
    assert o.take(0.0, 10) == []  # one at a time per node
    o.put("a", pub("/t", ["p1", "p2", "p3"]))  # the one in flight is not touched: a new one queues
    o.done("a", first[0][1], 0.1)
    assert sent(o.take(0.1, 10)) == [("a", "paramUpdate", ["/k/", 1])]


def test_a_node_that_answers_gets_every_param_update_one_that_does_not_only_the_last_per_key():
    o = Outbox(backoff_first=1.0)
    o.put("a", pub("/busy", []))
    busy = o.take(0.0, 1)[0][1]
    o.put("a", param("/k/", 1))
    o.put("a", param("/k/", 2))  # busy, not failing: both go, as rosmaster sends them
    o.done("a", busy, 0.0)
    order = []
    while o.queued():
        api, cb = o.take(0.0, 1)[0]
        order.append(cb.params[1:])
        o.done(api, cb, 0.0)
    assert order == [["/k/", 1], ["/k/", 2]]

    o.put("a", pub("/busy", []))
    busy = o.take(0.0, 1)[0][1]
    o.done("a", busy, 10.0, "no answer", timed_out=True)  # hung: kept, back-off till 11
    o.put("a", param("/a/", {"b": 1}))
    o.put("a", param("/a/b/", 2))
    o.put("a", param("/a/", {"b": 3}))  # must land after /a/b/ = 2, or the node would keep 2
    order = []
    now = 11.0
    while o.queued():
        api, cb = o.take(now, 1)[0]
        order.append(cb.params[1:])
        o.done(api, cb, now)
    assert order == [["/busy", []], ["/a/b/", 2], ["/a/", {"b": 3}]]


def test_slots_are_capped_and_freed():
    o = Outbox(max_in_flight=3)
    for i in range(5):
        o.put("n%d" % i, pub("/t", []))
    taken = o.take(0.0, 100)
    assert [api for api, _ in taken] == ["n0", "n1", "n2"]
    assert not o.can_take()
    o.done("n1", taken[1][1], 0.5)
    assert [api for api, _ in o.take(0.5, 100)] == ["n3"]


def test_nodes_waiting_for_a_slot_take_turns_by_topic():
    o = Outbox(max_in_flight=2)
    for i in range(1000):
        o.put("h%d" % i, pub("/big", ["p"]))
    busy = o.take(0.0, 100)  # h0 and h1: the slots are full
    o.put("small", pub("/small", ["q"]))
    o.put("h5", pub("/small", ["q"]))  # behind h5's /big: a node's own order holds
    for api, cb in busy:
        o.done(api, cb, 0.1)
    assert [api for api, _ in o.take(0.1, 2)] == ["h2", "small"]  # a turn each: not behind h3 ... h999


def test_failing_nodes_back_off_share_a_small_lane_and_never_hold_up_healthy_ones():
    o = Outbox(max_in_flight=10, max_failing=2, backoff_first=1.0, backoff_max=4.0)
    hung = ["h%d" % i for i in range(8)]
    for api in hung:
        o.put(api, pub("/t", ["p"]))
    calls = o.take(0.0, 100)
    assert len(calls) == 8
    for api, cb in calls:  # all time out at t=10
        o.done(api, cb, 10.0, "no answer", timed_out=True)
    assert [u.api for u in o.unreachable()] == hung
    assert o.take(10.5, 100) == []  # backing off (1 s)
    retried = o.take(11.0, 100)
    assert len(retried) == 2  # the lane: the other six wait although 8 slots are free
    assert sent(retried)[0] == ("h0", "publisherUpdate", ["/t", ["p"]])  # the same update, sent again
    o.put("healthy", pub("/u", ["q"]))
    assert [api for api, _ in o.take(11.0, 100)] == ["healthy"]  # not behind the failing ones


def test_back_off_doubles_up_to_its_cap():
    o = Outbox(backoff_first=1.0, backoff_max=4.0)
    o.put("n", pub("/t", ["p"]))
    now = 0.0
    waits = []
    for _ in range(5):
        api, cb = o.take(now, 1)[0]
        now += 10.0
        o.done(api, cb, now, "no answer", timed_out=True)
        assert o.take(now, 1) == []
        waits.append(o.next_wakeup() - now)
        now = o.next_wakeup()
    assert waits == [1.0, 2.0, 4.0, 4.0, 4.0]
    assert o.unreachable()[0].failures == 5
    assert o.unreachable()[0].since == 10.0


def test_a_failing_node_keeps_only_the_latest_update_per_topic_and_recovers_on_an_answer():
    o = Outbox(backoff_first=1.0)
    o.put("n", pub("/t", ["p1"]))
    cb = o.take(0.0, 1)[0][1]
    o.put("n", pub("/t", ["p1", "p2"]))  # while the first hangs
    o.done("n", cb, 10.0, "no answer", timed_out=True)  # superseded: not queued again
    o.put("n", pub("/t", ["p1", "p2", "p3"]))
    assert o.queued() == 1
    assert o.take(10.5, 10) == []
    api, cb = o.take(11.0, 10)[0]
    assert cb.params[2] == ["p1", "p2", "p3"]
    o.done(api, cb, 11.1)
    assert o.unreachable() == []
    o.put("n", pub("/t", []))
    assert len(o.take(11.1, 10)) == 1  # healthy again: no back-off


def test_forget_drops_what_a_gone_node_is_owed_but_a_shutdown_is_tried_once():
    o = Outbox(backoff_first=1.0)
    o.put("n", pub("/t", ["p"]))
    cb = o.take(0.0, 1)[0][1]
    o.put("n", param("/k/", 1))
    o.put("n", Callback("shutdown", ["/master", "bye"], once=True))
    o.forget("n")
    o.done("n", cb, 10.0, "no answer", timed_out=True)  # not retried: it is no longer registered
    assert o.unreachable() == []
    got = o.take(11.0, 10)
    assert sent(got) == [("n", "shutdown", ["bye"])]
    o.done("n", got[0][1], 11.0, "refused")
    assert o.queued() == 0
    assert o.take(100.0, 10) == []
    assert o.next_wakeup() is None or o.take(o.next_wakeup(), 10) == []


def test_forget_leaves_a_node_that_answers_what_is_queued_for_it_once():
    o = Outbox()
    o.put("n", pub("/t", ["p"]))
    api, cb = o.take(0.0, 1)[0]
    o.put("n", param("/k/", 1))
    o.forget("n")  # it unregistered: what was queued goes as rosmaster would send it
    o.done(api, cb, 0.1)
    api, cb = o.take(0.1, 1)[0]
    assert cb.params[1:] == ["/k/", 1]
    o.done(api, cb, 0.2, "reset")
    assert o.queued() == 0 and o.unreachable() == [] and o.take(0.2, 1) == []


def test_a_node_registering_again_is_owed_its_updates_again():
    o = Outbox()
    o.put("n", pub("/t", ["p"]))
    cb = o.take(0.0, 1)[0][1]
    o.forget("n")
    o.put("n", pub("/t", ["p", "q"]))  # the same API registered again
    o.done("n", cb, 1.0, "reset")
    assert o.unreachable()[0].api == "n"
    assert o.queued() == 1


def test_a_full_queue_drops_its_oldest():
    o = Outbox(max_queued=3)
    o.put("n", pub("/busy", []))
    o.take(0.0, 1)
    for i in range(5):
        o.put("n", param("/k%d/" % i, i))
    assert o.dropped == 2
    assert o.queued() == 4  # three queued, one in flight


def test_a_refused_call_is_dropped_as_rosmaster_drops_it_and_the_next_goes_at_once():
    o = Outbox(backoff_first=1.0)
    o.put("n", pub("/t", ["p"]))
    api, cb = o.take(0.0, 1)[0]
    o.put("n", param("/k/", 1))
    o.done(api, cb, 0.01, "[Errno 111] Connect call failed")
    (u,) = o.unreachable()
    assert (u.failures, u.queued) == (1, 1)  # reported; only the paramUpdate is left
    assert sent(o.take(0.01, 10)) == [("n", "paramUpdate", ["/k/", 1])]  # no back-off
