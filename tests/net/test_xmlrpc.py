"""The XML-RPC codec (against the stdlib's reading of it) and the asyncio server under hostile input."""

from __future__ import annotations

import asyncio
import os
import socket
import time
import xmlrpc.client

import pytest
from hypothesis import given, settings, strategies as st

from launcher.net import xmlrpc as X
from launcher.net import xmlrpc_codec as C
from launcher.net import xmlrpc_server as S

from helpers import ROOT, free_port, until

# ---------------------------------------------------------------------------
# codec
# ---------------------------------------------------------------------------

xml_text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\r\x00")
                   .filter(lambda c: c in "\t\n" or ord(c) >= 0x20 and c not in "\ufffe\uffff"), max_size=20)
values = st.recursive(
    st.one_of(st.integers(X.MININT, X.MAXINT), st.booleans(), xml_text,
              st.floats(allow_nan=False), st.binary(max_size=20)),
    lambda children: st.one_of(st.lists(children, max_size=4),
                               st.dictionaries(xml_text, children, max_size=4)),
    max_leaves=20)


def _std(v):
    """The stdlib's view of a value (bytes come back as Binary there)."""
    if isinstance(v, (bytes, bytearray)):
        return xmlrpc.client.Binary(bytes(v))
    if isinstance(v, list):
        return [_std(x) for x in v]
    if isinstance(v, dict):
        return {k: _std(x) for k, x in v.items()}
    return v


@settings(max_examples=200, deadline=None)
@given(st.lists(values, max_size=4))
def test_request_roundtrip_through_stdlib(params):
    method, got = X.loads_request(xmlrpc.client.dumps(tuple(_std(p) for p in params), "m.x").encode())
    assert method == "m.x"
    assert got == params
    std_params, std_method = xmlrpc.client.loads(X.dumps_request("a.b", params))
    assert std_method == "a.b"
    assert list(std_params) == [_std(p) for p in params]


@settings(max_examples=200, deadline=None)
@given(values)
def test_response_roundtrip_through_stdlib(value):
    assert xmlrpc.client.loads(X.dumps_response(value))[0][0] == _std(value)
    assert X.loads_response(xmlrpc.client.dumps((_std(value),), methodresponse=True).encode()) == value


def test_untyped_value_i8_nil_and_datetime():
    body = (b"<?xml version='1.0'?><methodCall><methodName>f</methodName><params>"
            b"<param><value>bare text</value></param><param><value></value></param>"
            b"<param><value><i8>4294967296</i8></value></param><param><value><nil/></value></param>"
            b"<param><value><i4> 7 </i4></value></param>"
            b"<param><value><dateTime.iso8601>20200102T03:04:05</dateTime.iso8601></value></param>"
            b"</params></methodCall>")
    method, params = X.loads_request(body)
    assert params[:5] == ["bare text", "", 4294967296, None, 7]
    assert params[5].value == "20200102T03:04:05"
    assert b"<dateTime.iso8601>20200102T03:04:05</dateTime.iso8601>" in X.dumps_response(params[5])


def test_a_python_datetime_is_sent_as_the_stdlib_sends_it():
    import datetime  # (the codec does not import it: a value of its type means the caller has)
    when = datetime.datetime(2020, 1, 2, 3, 4, 5)
    body = X.dumps_response([when])
    assert b"<dateTime.iso8601>20200102T03:04:05</dateTime.iso8601>" in body
    assert xmlrpc.client.loads(body, use_datetime=True)[0][0] == [when]


def test_out_of_int32_values_and_none_cannot_be_sent():
    with pytest.raises(OverflowError):
        X.dumps_response([1, {"a": 2**31}])
    with pytest.raises(TypeError):
        X.dumps_response(None)


def test_fault_roundtrip():
    with pytest.raises(X.Fault) as e:
        X.loads_response(X.dumps_fault(3, "a < b & c"))
    assert (e.value.faultCode, e.value.faultString) == (3, "a < b & c")
    with pytest.raises(xmlrpc.client.Fault) as e2:
        xmlrpc.client.loads(X.dumps_fault(3, "x"))
    assert e2.value.faultCode == 3


@pytest.mark.parametrize("body", [
    # external entity (XXE)
    b"<?xml version='1.0'?><!DOCTYPE m [<!ENTITY x SYSTEM 'file:///etc/passwd'>]>"
    b"<methodCall><methodName>f</methodName><params><param><value>&x;</value></param></params></methodCall>",
    # entity expansion (billion laughs)
    b"<?xml version='1.0'?><!DOCTYPE m [<!ENTITY a 'aaaaaaaaaa'><!ENTITY b '&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;'>"
    b"<!ENTITY c '&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;'>]>"
    b"<methodCall><methodName>f</methodName><params><param><value>&c;</value></param></params></methodCall>",
    # any DTD at all
    b"<?xml version='1.0'?><!DOCTYPE methodCall SYSTEM 'http://example.invalid/x.dtd'>"
    b"<methodCall><methodName>f</methodName><params/></methodCall>",
    # undeclared entity
    b"<methodCall><methodName>f</methodName><params><param><value>&nope;</value></param></params></methodCall>",
    b"not xml at all",
    b"<methodCall><methodName>f</methodName><params><param><value><int>x</int></value></param></params></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value><boolean>2</boolean></value></param></params></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value><bogus/></value></param></params></methodCall>",
    b"<methodResponse><params/></methodResponse>",
    b"<methodCall><params/></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value><int>" + b"9" * 10000 + b"</int></value></param></params></methodCall>",
])
def test_hostile_or_malformed_requests_are_refused(body):
    with pytest.raises(X.XmlRpcError):
        X.loads_request(body)


def test_nesting_depth_is_bounded():
    deep = b"<value><array><data>" * (X.MAX_DEPTH + 5) + b"<value>x</value>" + b"</data></array></value>" * (X.MAX_DEPTH + 5)
    with pytest.raises(X.XmlRpcError):
        X.loads_request(b"<methodCall><methodName>f</methodName><params><param>" + deep + b"</param></params></methodCall>")
    ok = b"<value><array><data>" * 50 + b"<value>x</value>" + b"</data></array></value>" * 50
    _, params = X.loads_request(b"<methodCall><methodName>f</methodName><params><param>" + ok + b"</param></params></methodCall>")
    v = params[0]
    for _ in range(50):
        v = v[0]
    assert v == "x"


def test_multicall_collects_results_and_faults():
    def dispatch(m, p):
        if m == "ok":
            return p[0]
        raise X.Fault(7, "bad")
    out = S.multicall(dispatch, [{"methodName": "ok", "params": [5]}, {"methodName": "no", "params": []},
                                 "junk"])
    assert out[0] == [5]
    assert out[1] == {"faultCode": 7, "faultString": "bad"}
    assert out[2]["faultCode"] == 1


# ---------------------------------------------------------------------------
# server, over real loopback sockets
# ---------------------------------------------------------------------------

def _dispatch(method, params):
    if method == "echo":
        return params
    if method == "later":
        async def reply():
            await asyncio.sleep(params[0])
            return params[1]
        return reply()
    if method == "too_big":
        return 2**40
    if method == "boom":
        raise RuntimeError("boom")
    raise X.Fault(1, 'method "%s" is not supported' % method)


class ServerThread:
    """Runs an XmlRpcServer on its own loop in a thread so that blocking clients can hit it."""

    def __init__(self, **kw):
        import threading
        self.loop = asyncio.new_event_loop()
        self.server = S.XmlRpcServer(_dispatch, "127.0.0.1", 0, multicall=True, **kw)
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        asyncio.run_coroutine_threadsafe(self.server.start(), self.loop).result(5)
        self.port = self.server.port
        self.uri = "http://127.0.0.1:%d/" % self.port

    def close(self):
        asyncio.run_coroutine_threadsafe(self.server.stop(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def server():
    s = ServerThread(request_timeout=1.0)
    yield s
    s.close()


def _raw(port, data: bytes, timeout=5.0) -> bytes:
    """Send raw bytes, read until the server closes or `timeout`."""
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(data)
        chunks = []
        try:
            while True:
                c = s.recv(65536)
                if not c:
                    break
                chunks.append(c)
        except socket.timeout:
            pass
        return b"".join(chunks)


def _post(body: bytes, path=b"/", extra=b"") -> bytes:
    return b"POST %s HTTP/1.1\r\nHost: x\r\nContent-Length: %d\r\n%s\r\n" % (path, len(body), extra) + body


def _alive(s):
    return xmlrpc.client.ServerProxy(s.uri).echo("still") == ["still"]


def test_stdlib_client_paths_faults_and_multicall(server):
    sp = xmlrpc.client.ServerProxy(server.uri)
    assert sp.echo(1, "a", [True, 2.5], {"k": "v"}) == [1, "a", [True, 2.5], {"k": "v"}]
    assert xmlrpc.client.ServerProxy(server.uri + "RPC2").echo("r") == ["r"]
    assert sp.later(0.01, "async") == "async"
    with pytest.raises(xmlrpc.client.Fault) as e:
        sp.too_big()
    assert "OverflowError" in e.value.faultString
    with pytest.raises(xmlrpc.client.Fault):
        sp.nope()
    with pytest.raises(xmlrpc.client.Fault) as e:
        sp.boom()
    assert "boom" in e.value.faultString
    mc = xmlrpc.client.MultiCall(sp)
    mc.echo(1)
    mc.later(0.01, "x")
    results = mc()
    assert list(results) == [[1], "x"]


def test_keep_alive_and_pipelined_replies_stay_in_order(server):
    body_slow = X.dumps_request("later", [0.1, "first"])
    body_fast = X.dumps_request("echo", ["second"])
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall(_post(body_slow) + _post(body_fast))
        data = b""
        deadline = time.time() + 5
        while data.count(b"</methodResponse>") < 2 and time.time() < deadline:
            data += s.recv(65536)
        # same connection still usable afterwards (keep-alive)
        s.sendall(_post(X.dumps_request("echo", ["third"])))
        more = b""
        while b"</methodResponse>" not in more and time.time() < deadline:
            more += s.recv(65536)
    assert data.index(b"first") < data.index(b"second")
    assert b"third" in more


def test_http_1_0_and_connection_close_close_the_connection(server):
    body = X.dumps_request("echo", ["x"])
    out = _raw(server.port, b"POST / HTTP/1.0\r\nContent-Length: %d\r\n\r\n" % len(body) + body)
    assert out.startswith(b"HTTP/1.1 200") and b"<string>x</string>" in out
    out = _raw(server.port, _post(body, extra=b"Connection: close\r\n"))
    assert out.startswith(b"HTTP/1.1 200")


@pytest.mark.parametrize("request_bytes,status", [
    (_post(X.dumps_request("echo", []), path=b"/elsewhere", extra=b"Connection: close\r\n"), b"404"),
    (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", b"501"),
    (b"POST / HTTP/1.1\r\nHost: x\r\n\r\n", b"411"),
    (b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n", b"501"),
    (b"POST / HTTP/1.1\r\nContent-Length: 99999999999\r\n\r\n", b"413"),
    (b"POST / HTTP/1.1\r\nContent-Length: -1\r\n\r\n", b"400"),
    (b"garbage\r\n\r\n", b"400"),
    (b"POST / HTTP/1.1\r\n" + b"X-A: b\r\n" * 200 + b"Content-Length: 0\r\n\r\n", b"431"),
    (b"POST / HTTP/1.1\r\nX-Long: " + b"a" * 40000 + b"\r\n\r\n", b"431"),
])
def test_bad_http_gets_an_http_error_and_the_server_keeps_serving(server, request_bytes, status):
    out = _raw(server.port, request_bytes)
    assert out.split(b" ", 2)[1] == status, out[:200]
    assert _alive(server)


@pytest.mark.parametrize("body", [
    b"<?xml version='1.0'?><!DOCTYPE m [<!ENTITY a 'aaaaaaaaaa'><!ENTITY b '&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;'>]>"
    b"<methodCall><methodName>echo</methodName><params><param><value>&b;</value></param></params></methodCall>",
    b"<methodCall><methodName>echo</methodName><params><param><value><int>12",
    b"\xff\xfe garbage",
])
def test_bad_xml_gets_a_fault_and_the_server_keeps_serving(server, body):
    out = _raw(server.port, _post(body, extra=b"Connection: close\r\n"))
    assert out.startswith(b"HTTP/1.1 200")
    with pytest.raises(X.Fault):
        X.loads_response(out.split(b"\r\n\r\n", 1)[1])
    assert _alive(server)


def test_slow_client_times_out_without_blocking_others(server):
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as slow:
        slow.sendall(b"POST / HTTP/1.1\r\nContent-Length: 100\r\n\r\n<methodCall>")
        t0 = time.time()
        assert _alive(server)  # served while the slow request is pending
        assert time.time() - t0 < 0.5
        out = b""
        while True:
            c = slow.recv(4096)
            if not c:
                break
            out += c
        assert out.startswith(b"HTTP/1.1 408")
        assert 0.5 < time.time() - t0 < 4


def test_client_that_never_reads_does_not_wedge_the_server(server):
    big = X.dumps_request("echo", ["y" * 200000])
    with socket.create_connection(("127.0.0.1", server.port), timeout=1) as hog:
        hog.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        try:
            for _ in range(200):
                hog.sendall(_post(big))
        except (socket.timeout, OSError):
            pass  # the server stopped reading from us: exactly the point
        assert _alive(server)


def test_async_client_call_and_errors():
    async def scenario():
        s = S.XmlRpcServer(_dispatch, "127.0.0.1", 0)
        await s.start()
        uri = "http://127.0.0.1:%d/" % s.port
        try:
            assert await X.call(uri, "echo", 1, "two") == [1, "two"]
            with pytest.raises(X.Fault):
                await X.call(uri, "nope")
            with pytest.raises(X.XmlRpcError):
                await X.call(uri + "elsewhere", "echo")
            with pytest.raises(asyncio.TimeoutError):
                await X.call(uri, "later", 2.0, "x", timeout=0.2)
        finally:
            await s.stop()
        with pytest.raises(OSError):
            await X.call(uri, "echo")
    asyncio.run(scenario())


def test_async_client_connect_deadline_is_its_own():
    """A server whose accept queue is full takes no more connections: the connection's own deadline ends the
    wait (what a node on a machine gone from the network looks like), well before the call's."""
    async def scenario():
        with socket.socket() as full:
            full.bind(("127.0.0.1", 0))
            full.listen(0)
            port = full.getsockname()[1]
            queued = []
            try:
                for _ in range(8):  # fill the accept queue; later SYNs get no answer
                    c = socket.socket()
                    c.setblocking(False)
                    c.connect_ex(("127.0.0.1", port))
                    queued.append(c)
                loop = asyncio.get_running_loop()
                t0 = loop.time()
                with pytest.raises(TimeoutError, match="no connection"):
                    await X.call("http://127.0.0.1:%d/" % port, "getPid", "/x", timeout=10, connect_timeout=0.3)
                assert loop.time() - t0 < 2
            finally:
                for c in queued:
                    c.close()
    asyncio.run(scenario())


def test_a_call_cancelled_as_its_connection_is_made_ends_and_closes_it(monkeypatch):
    """The cancel comes in the very step the connection is made (a service stopped as its watcher called the
    master): the call raises it (it ran on before, and the launch's stop waited on it for good), and the
    connection is closed at once, with no error left behind on its reply."""
    async def scenario():
        loop = asyncio.get_running_loop()
        errors = []
        loop.set_exception_handler(lambda _loop, context: errors.append(context.get("message")))
        with socket.socket() as listener:
            listener.bind(("127.0.0.1", 0))
            listener.listen(1)
            port = listener.getsockname()[1]
            task = None
            made = X._Exchange.connection_made

            def cancelled_there(self, transport):
                made(self, transport)
                task.cancel()
            monkeypatch.setattr(X._Exchange, "connection_made", cancelled_there)
            task = asyncio.ensure_future(X.call("http://127.0.0.1:%d/" % port, "getPid", "/x", timeout=10))
            with pytest.raises(asyncio.CancelledError):
                await task
            listener.setblocking(False)
            peer, _ = await loop.sock_accept(listener)
            with peer:
                request = b""
                while True:  # (the request, then the end: the client closed its side)
                    data = await asyncio.wait_for(loop.sock_recv(peer, 65536), 5.0)
                    if not data:
                        break
                    request += data
                assert request.startswith(b"POST ")
            import gc
            gc.collect()  # (a future whose error nobody read says so when collected)
            await asyncio.sleep(0)
        assert errors == []
    asyncio.run(scenario())


def test_port_taken_raises_oserror():
    async def scenario():
        a = S.XmlRpcServer(_dispatch, "127.0.0.1", 0)
        await a.start()
        try:
            b = S.XmlRpcServer(_dispatch, "127.0.0.1", a.port)
            with pytest.raises(OSError):
                await b.start()
        finally:
            await a.stop()
    asyncio.run(scenario())


# ---------------------------------------------------------------------------
# the fast request path reads exactly what expat reads
# ---------------------------------------------------------------------------

flat_values = st.one_of(st.integers(X.MININT, X.MAXINT), st.booleans(), st.floats(allow_nan=False),
                        st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=30))


def _expat_only(body: bytes):
    u = C._parse(body)
    return u.method, u.stack


def _read_as_expat_reads(body: bytes):
    """loads_request reads `body` as expat does, or refuses it as expat does: what expat read (None: refused)."""
    try:
        want = _expat_only(body)
    except X.XmlRpcError:
        with pytest.raises(X.XmlRpcError):
            X.loads_request(body)
        return None
    assert X.loads_request(body) == want
    return want


@settings(max_examples=300, deadline=None)
@given(st.lists(flat_values, max_size=5), st.sampled_from(["getParam", "system.multicall", "a_b.c"]))
def test_fast_path_agrees_with_expat_for_stdlib_requests(params, method):
    body = xmlrpc.client.dumps(tuple(params), method).encode()
    _read_as_expat_reads(body)


# what roscpp's XmlRpc++ sends (captured from a roscpp node): CRLF between tags, untyped strings
ROSCPP_REQUEST = (b'<?xml version="1.0"?>\r\n<methodCall><methodName>hasParam</methodName>\r\n<params><param><value>'
                  b'/n1</value></param><param><value>/tcp_keepalive</value></param></params></methodCall>\r\n')


def test_roscpps_requests_take_the_fast_path():
    """Every roscpp node's calls to the master (a dozen at each start) are read without expat."""
    assert C._loads_request_fast(ROSCPP_REQUEST) == _expat_only(ROSCPP_REQUEST) == ("hasParam", ["/n1", "/tcp_keepalive"])


@settings(max_examples=200, deadline=None)
@given(st.lists(flat_values, max_size=5), st.sampled_from([b"\r\n", b"\r", b" \r\n\t"]))
def test_fast_path_agrees_with_expat_with_crs_between_tags(params, ending):
    """CRs between the tags (roscpp's CRLF lines) are whitespace, read on the fast path; a CR in a value, which XML
    reads as a LF, goes to expat."""
    body = xmlrpc.client.dumps(tuple(params), "getParam").encode().replace(b"\n", ending)
    want = _read_as_expat_reads(body)
    if want is not None and not any(isinstance(p, str) and set(p) & set("\r\n&<>") for p in params):  # (no CR, no entity: fast)
        assert C._loads_request_fast(body) == want


@pytest.mark.parametrize("body", [
    # XmlRpc++ (roscpp): untyped strings, <i4>, no prolog
    b"<?xml version=\"1.0\"?>\r\n<methodCall><methodName>getParam</methodName>\r\n<params><param><value>/node</value>"
    b"</param><param><value>/p</value></param></params></methodCall>\r\n",
    b"<methodCall><methodName>setParam</methodName><params><param><value>/n</value></param><param><value>/p"
    b"</value></param><param><value><i4>7</i4></value></param></params></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value>a\r\nb</value></param></params></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value><string>&lt;&amp;&#65;</string></value>"
    b"</param></params></methodCall>",
    b"<?xml version='1.0' encoding='iso-8859-1'?><methodCall><methodName>f</methodName><params><param><value>"
    b"\xe9</value></param></params></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value> <int>3</int> </value></param></params></methodCall>",
    b"<methodCall><methodName>f</methodName><params><param><value><boolean>true</boolean></value></param>"
    b"</params></methodCall>",
    b"<methodCall><methodName>f</methodName><params/></methodCall>",
    b"<methodCall><methodName>f</methodName></methodCall>",
])
def test_fast_path_agrees_with_expat_on_other_shapes(body):
    _read_as_expat_reads(body)


@pytest.mark.parametrize("reply", [
    b"HTTP/1.1 200 OK\r\nContent-Length: 999999999999\r\n\r\n",
    b"HTTP/1.1 200 OK\r\nX-Long: " + b"a" * 100000 + b"\r\n\r\n",
    b"NOT HTTP\r\n\r\n",
    b"HTTP/1.1 200 OK\r\nContent-Length: 50\r\n\r\n<methodResponse>",
    b"HTTP/1.1 200 OK\r\n\r\n<methodResponse><params><param><value>unterminated",
], ids=["huge-length", "long-header", "not-http", "short-body", "bad-xml-until-eof"])
def test_client_survives_hostile_servers(reply):
    async def scenario():
        async def serve(reader, writer):
            await reader.read(65536)
            writer.write(reply)
            await writer.drain()
            writer.close()
        srv = await asyncio.start_server(serve, "127.0.0.1", 0)
        port = srv.sockets[0].getsockname()[1]
        try:
            with pytest.raises(X.XmlRpcError):
                await X.call("http://127.0.0.1:%d/" % port, "getPid", "/x", timeout=5)
        finally:
            srv.close()
            await srv.wait_closed()
    asyncio.run(scenario())


def test_large_requests_and_long_multicalls_do_not_starve_other_clients(server):
    import select
    calls = [{"methodName": "echo", "params": ["x" * 20, i]} for i in range(60000)]
    body = xmlrpc.client.dumps((calls,), "system.multicall").encode()
    assert len(body) > S.LARGE_REQUEST
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as big:
        t0 = time.time()
        big.sendall(_post(body))
        worst = 0.0
        served = 0
        while not select.select([big], [], [], 0)[0]:
            t1 = time.time()
            assert _alive(server)
            worst = max(worst, time.time() - t1)
            served += 1
        answered_after = time.time() - t0
        reply = b""
        while not reply.endswith(b"</methodResponse>\n"):
            reply += big.recv(1 << 20)
    # small calls kept being answered quickly while the big one was parsed and run
    assert served >= 3
    assert worst < answered_after / 2, (worst, answered_after)
    result = xmlrpc.client.loads(reply.split(b"\r\n\r\n", 1)[1])[0][0]
    assert len(result) == 60000 and result[59999] == [["x" * 20, 59999]]


SEED_REQUESTS = [
    xmlrpc.client.dumps(("/node", "/p", {"a": [1, 2.5, True, "x"], "b": xmlrpc.client.Binary(b"\x00\xff")}),
                        "setParam").encode(),
    xmlrpc.client.dumps(([{"methodName": "getPid", "params": ["/n"]}],), "system.multicall").encode(),
    b"<methodCall><methodName>getParam</methodName><params><param><value>/n</value></param>"
    b"<param><value><i4>7</i4></value></param></params></methodCall>",
]


@settings(max_examples=500, deadline=None)
@given(st.sampled_from(SEED_REQUESTS), st.lists(st.tuples(st.integers(0, 400), st.integers(0, 8), st.binary(max_size=8)),
                                                max_size=4))
def test_mutated_requests_only_ever_raise_xmlrpcerror(seed, edits):
    data = bytearray(seed)
    for pos, cut, insert in edits:
        pos = min(pos, len(data))
        data[pos:pos + cut] = insert
    try:
        method, params = X.loads_request(bytes(data))
    except X.XmlRpcError:
        return
    assert isinstance(method, str) and isinstance(params, list)
    try:
        X.dumps_response(params)  # whatever was read can be answered (or refused cleanly)
    except (OverflowError, TypeError):
        pass


def test_mutated_http_never_wedges_the_server(server):
    rng = __import__("random").Random(5)
    seed = _post(X.dumps_request("echo", ["x", 1]))
    for _ in range(300):
        data = bytearray(seed)
        for _ in range(rng.randint(1, 4)):
            pos = rng.randrange(len(data) + 1)
            data[pos:pos + rng.randint(0, 6)] = bytes(rng.randrange(256) for _ in range(rng.randint(0, 6)))
        with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
            s.sendall(bytes(data) * rng.randint(1, 2))
            s.shutdown(socket.SHUT_WR)
            out = b""
            while True:
                c = s.recv(65536)
                if not c:
                    break
                out += c
        assert out == b"" or out.startswith(b"HTTP/1.1 "), out[:100]
    assert _alive(server)


def test_half_closed_client_still_gets_its_asynchronous_reply(server):
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall(_post(X.dumps_request("later", [0.05, "late"])))
        s.shutdown(socket.SHUT_WR)
        out = b""
        while True:
            c = s.recv(65536)
            if not c:
                break
            out += c
    assert out.startswith(b"HTTP/1.1 200") and b"late" in out


def test_slow_request_after_a_long_idle_time_still_times_out():
    s = ServerThread(request_timeout=0.5, idle_timeout=60)
    try:
        with socket.create_connection(("127.0.0.1", s.port), timeout=10) as c:
            # one complete call first: an idle keep-alive connection (a fresh one that sends nothing
            # is closed at the header deadline)
            c.sendall(_post(X.dumps_request("echo", ["x"])))
            reply = b""
            while b"</methodResponse>" not in reply:
                reply += c.recv(4096)
            t_idle = time.time()
            while time.time() - t_idle < 0.8:  # past the first timer: it now waits for the idle deadline
                time.sleep(0.05)
            c.sendall(b"POST / HTTP/1.1\r\nContent-Length: 100\r\n\r\n<methodCall>")
            t0 = time.time()
            out = b""
            while True:
                chunk = c.recv(4096)
                if not chunk:
                    break
                out += chunk
            assert out.startswith(b"HTTP/1.1 408")
            assert time.time() - t0 < 5
    finally:
        s.close()


def test_a_flood_of_idle_connections_cannot_lock_clients_out():
    s = ServerThread(max_connections=20)
    try:
        hogs = [socket.create_connection(("127.0.0.1", s.port)) for _ in range(60)]
        try:
            # each new connection evicted the longest-idle one: real clients still get in
            assert xmlrpc.client.ServerProxy(s.uri).echo("in") == ["in"]
            assert len(s.server._connections) <= 20
        finally:
            for h in hogs:
                h.close()
    finally:
        s.close()


def test_stdlib_binary_is_sent_as_base64():
    assert b"<base64>AP8=</base64>" in X.dumps_response(xmlrpc.client.Binary(b"\x00\xff"))


def test_blocking_client_values_faults_and_http_errors(server):
    assert X.call_blocking(server.uri, "echo", 1, "a", [True, 2.5], {"k": "v"}) == [1, "a", [True, 2.5], {"k": "v"}]
    assert X.call_blocking(server.uri, "later", 0.01, "async") == "async"
    calls = [{"methodName": "echo", "params": ["x"]}, {"methodName": "nope", "params": []}]
    out = X.call_blocking(server.uri, "system.multicall", calls)
    assert out[0] == [["x"]] and out[1]["faultCode"] == 1
    with pytest.raises(X.Fault) as e:
        X.call_blocking(server.uri, "boom")
    assert "boom" in e.value.faultString
    with pytest.raises(X.XmlRpcError, match="HTTP 404"):
        X.call_blocking(server.uri + "elsewhere", "echo")
    with pytest.raises(X.XmlRpcError, match="not an http"):
        X.call_blocking("https://127.0.0.1:1/", "echo")


def test_blocking_client_refused_and_timeout():
    with pytest.raises(OSError):
        X.call_blocking("http://127.0.0.1:%d/" % free_port(), "echo", timeout=2.0)
    with socket.socket() as silent:  # accepts (backlog) but never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen(1)
        t0 = time.monotonic()
        with pytest.raises(OSError):  # socket.timeout
            X.call_blocking("http://127.0.0.1:%d/" % silent.getsockname()[1], "echo", timeout=0.3)
        assert time.monotonic() - t0 < 3.0


def test_blocking_client_reply_cut_short():
    import threading
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)

        def answer():
            c, _ = srv.accept()
            with c:
                c.recv(65536)
                c.sendall(b"HTTP/1.1 200 OK\r\nContent-Length: 500\r\n\r\n<?xml version='1.0'?>")
        t = threading.Thread(target=answer)
        t.start()
        with pytest.raises(X.XmlRpcError, match="before the reply was complete"):
            X.call_blocking("http://127.0.0.1:%d/" % srv.getsockname()[1], "echo", timeout=5.0)
        t.join(5)


def test_expect_100_continue_over_a_socket(server):
    body = X.dumps_request("echo", ["after-continue"])
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as c:
        c.sendall(b"POST / HTTP/1.1\r\nHost: x\r\nExpect: 100-continue\r\nContent-Length: %d\r\n\r\n" % len(body))
        interim = b""
        while b"\r\n\r\n" not in interim:
            interim += c.recv(4096)
        assert interim.startswith(b"HTTP/1.1 100 Continue\r\n\r\n")
        c.sendall(body)
        reply = interim[len(b"HTTP/1.1 100 Continue\r\n\r\n"):]
        while b"</methodResponse>" not in reply:
            reply += c.recv(4096)
    assert reply.startswith(b"HTTP/1.1 200") and b"after-continue" in reply


def test_a_connection_that_never_sends_a_head_is_closed_at_the_header_deadline():
    s = ServerThread(header_timeout=0.3, request_timeout=5.0, idle_timeout=60)
    try:
        with socket.create_connection(("127.0.0.1", s.port), timeout=5) as c:
            t0 = time.monotonic()
            assert c.recv(4096) == b""  # closed by the server, long before the idle deadline
            assert time.monotonic() - t0 < 3
    finally:
        s.close()


def test_at_the_cap_half_sent_connections_are_evicted_before_established_clients():
    s = ServerThread(max_connections=10)
    try:
        established = socket.create_connection(("127.0.0.1", s.port), timeout=5)
        established.sendall(_post(X.dumps_request("echo", ["one"])))
        reply = b""
        while b"</methodResponse>" not in reply:
            reply += established.recv(65536)
        hogs = []
        for _ in range(30):  # each new one takes the place of the oldest never-completed one
            h = socket.create_connection(("127.0.0.1", s.port))
            h.sendall(b"POST / HTTP/1.1\r\nContent-Le")
            hogs.append(h)
        try:
            established.sendall(_post(X.dumps_request("echo", ["two"])))
            reply = b""
            while b"</methodResponse>" not in reply:
                chunk = established.recv(65536)
                assert chunk, "the established keep-alive client was evicted"
                reply += chunk
            assert b"two" in reply
        finally:
            for h in hogs:
                h.close()
            established.close()
    finally:
        s.close()


_OUT_OF_FILES_SERVER = r"""
import asyncio, resource, sys
from launcher.net.xmlrpc_server import XmlRpcServer
resource.setrlimit(resource.RLIMIT_NOFILE, (64, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
async def main():
    s = XmlRpcServer(lambda m, p: p, "127.0.0.1", 0, max_connections=1000)  # a cap above the limit
    await s.start()
    print(s.port, flush=True)
    await asyncio.sleep(3600)
asyncio.run(main())
"""


def test_accept_out_of_files_backs_off_with_one_warning():
    import subprocess
    import sys
    proc = subprocess.Popen([sys.executable, "-c", _OUT_OF_FILES_SERVER], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=dict(os.environ, PYTHONPATH=ROOT))
    hogs = []
    try:
        port = int(proc.stdout.readline())
        for _ in range(120):  # more than the server's 64 files: accept() fails for a while
            h = socket.create_connection(("127.0.0.1", port), timeout=5)
            h.sendall(b"POST / HTTP/1.1\r\nContent-Le")
            hogs.append(h)
        import select
        ready, _, _ = select.select([proc.stderr], [], [], 10)  # the server has run out of files
        assert ready, "no warning"
        first = proc.stderr.readline().decode(errors="replace")
        assert "out of open files" in first
        for h in hogs:
            h.close()
        hogs = []
        # once files are free again, clients are served
        assert until(lambda: X.call_blocking("http://127.0.0.1:%d/" % port, "echo", "back", timeout=2), 10,
                     what="an answer", errors=(OSError,)) == ["back"]
    finally:
        for h in hogs:
            h.close()
        proc.terminate()
        _out, err = proc.communicate(timeout=10)
    assert err.decode(errors="replace").splitlines() == [], "one warning, not one per failed accept"


def test_deadline_policy_on_a_fake_clock():
    """A connection's deadlines as a pure policy: a head within `header` s, a body within `request` s of the
    request's start, idle keep-alive for `idle` s; the client is not timed while our own reply is pending."""
    from launcher.net.xmlrpc_server import Deadlines
    d = Deadlines(header=10.0, request=30.0, idle=3600.0)
    # a head trickling in since t=100 (slowloris): due at 110, then 408
    assert d.next(now=105.0, busy=False, partial_since=100.0, body_pending=False, last_activity=0.0) == 110.0
    assert d.verdict(109.9, 110.0, busy=False, buffered=True) == "wait"
    assert d.verdict(110.0, 110.0, busy=False, buffered=True) == "408"
    # its head is in, the body is not: the whole request is due at 130
    assert d.next(now=111.0, busy=False, partial_since=100.0, body_pending=True, last_activity=0.0) == 130.0
    # idle between requests: closed (no 408, nothing was being sent) an hour after the last one
    assert d.next(now=200.0, busy=False, partial_since=None, body_pending=False, last_activity=150.0) == 3750.0
    assert d.verdict(3750.0, 3750.0, busy=False, buffered=False) == "close"
    # our reply pending: the deadline moves with the clock
    assert d.next(now=500.0, busy=True, partial_since=100.0, body_pending=True, last_activity=0.0) == 530.0


def test_a_connection_accepted_as_the_server_stops_is_closed_unanswered():
    """A client that connected just before the server stopped (accepted, its transport not made yet: a follower's
    next long poll, sent the moment the last answer came) is closed without an answer. Served, its call would be
    cancelled with the loop's end and answered "call cancelled", a fault a client cannot tell from a failing
    method (it made `launcher events -f` end with a traceback as its launch ended)."""
    async def scenario():
        s = S.XmlRpcServer(_dispatch, "127.0.0.1", 0)
        await s.start()
        client = socket.create_connection(("127.0.0.1", s.port), timeout=5)
        try:
            client.sendall(b"POST / HTTP/1.1\r\nContent-Length: %d\r\n\r\n" % len(LATER) + LATER)
            listener = s._listeners[0]
            until(lambda: _pending(listener), 5, 0.01, what="the connection in the listen queue")
            s._accept(listener)  # (accepted: its transport is a task that has not run yet)
            await s.stop()
            await asyncio.sleep(0.2)  # (that task runs now, with the server stopped)
            loop = asyncio.get_running_loop()
            try:
                reply = await loop.run_in_executor(None, client.recv, 65536)
            except ConnectionResetError:
                reply = b""  # (closed with its request unread: the kernel resets the connection)
            assert reply == b"", reply
        finally:
            client.close()
    asyncio.run(scenario())


LATER = C.dumps_request("later", (0.05, "x"))


def _pending(listener: socket.socket) -> bool:
    """A connection waits in `listener`'s queue (the kernel says it is readable)."""
    import select
    return bool(select.select([listener], [], [], 0)[0])
