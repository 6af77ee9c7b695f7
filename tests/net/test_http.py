"""launcher.net.http: HTTP/1.1 framing without sockets (bytes in, events out)."""

import pytest

from launcher.net import http as H


def _req(body=b"<methodCall/>", path=b"/", extra=b"", version=b"HTTP/1.1"):
    return b"POST %s %s\r\nHost: x\r\nContent-Length: %d\r\n%s\r\n" % (path, version, len(body), extra) + body


def _events(reader, chunks):
    """Feed `chunks` one by one, collecting every event until NEED_DATA after each."""
    out = []
    for chunk in chunks:
        reader.receive_data(chunk)
        while True:
            ev = reader.next_event()
            if ev is H.NEED_DATA:
                break
            out.append(ev)
    return out


def _request_reader(**kw):
    return H.RequestReader(H.RequestLimits(**kw))


def test_one_request_in_one_chunk():
    assert _events(_request_reader(), [_req(b"abc")]) == [H.Request(b"/", b"abc", True)]


def test_pipelined_requests_split_at_every_position_give_the_same_events():
    data = _req(b"first") + _req(b"second", path=b"/RPC2?x=1") + _req(b"", extra=b"Connection: close\r\n")
    want = [H.Request(b"/", b"first", True), H.Request(b"/RPC2", b"second", True, query=b"x=1"),
            H.Request(b"/", b"", False)]
    for cut in range(len(data) + 1):
        assert _events(_request_reader(), [data[:cut], data[cut:]]) == want, cut
    assert _events(_request_reader(), [bytes([b]) for b in data]) == want


def test_incomplete_request_needs_data_and_reports_what_is_pending():
    r = _request_reader()
    assert r.next_event() is H.NEED_DATA and not r.head_pending and r.buffered == 0
    r.receive_data(b"POST / HTTP/1.1\r\nContent-Le")
    assert r.next_event() is H.NEED_DATA and r.head_pending
    r.receive_data(b"ngth: 4\r\n\r\nab")
    assert r.next_event() is H.NEED_DATA and not r.head_pending and r.buffered == 2 + len(
        b"POST / HTTP/1.1\r\nContent-Length: 4\r\n\r\n")
    r.receive_data(b"cd")
    assert r.next_event() == H.Request(b"/", b"abcd", True)
    assert r.buffered == 0


@pytest.mark.parametrize("extra,version,keep_alive", [
    (b"", b"HTTP/1.1", True),
    (b"", b"HTTP/1.0", False),
    (b"Connection: Keep-Alive\r\n", b"HTTP/1.0", True),
    (b"connection: close\r\n", b"HTTP/1.1", False),
])
def test_keep_alive_follows_version_and_connection_header(extra, version, keep_alive):
    assert _events(_request_reader(), [_req(extra=extra, version=version)])[0].keep_alive is keep_alive


def test_absolute_target_is_reduced_to_its_path():
    assert _events(_request_reader(), [_req(path=b"http://host:11311/RPC2")])[0].target == b"/RPC2"


def test_expect_100_continue_is_announced_once_before_the_body():
    r = _request_reader()
    head = b"POST / HTTP/1.1\r\nContent-Length: 3\r\nExpect: 100-continue\r\n\r\n"
    r.receive_data(head)
    assert r.next_event() is H.CONTINUE
    assert r.next_event() is H.NEED_DATA
    r.receive_data(b"abc")
    assert r.next_event() == H.Request(b"/", b"abc", True)


@pytest.mark.parametrize("data,status", [
    (b"GARBAGE\r\n\r\n", 400),
    (b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", 501),
    (b"POST / HTTP/2.0\r\nContent-Length: 0\r\n\r\n", 400),
    (b"POST / HTTP/1.1\r\nHost: x\r\n\r\n", 411),
    (b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n5\r\nhello\r\n0\r\n\r\n", 501),
    (b"POST / HTTP/1.1\r\nContent-Length: x\r\n\r\n", 400),
    (b"POST / HTTP/1.1\r\nContent-Length: -1\r\n\r\n", 400),
    (b"POST / HTTP/1.1\r\nContent-Length: 3\r\nContent-Length: 4\r\n\r\nabcd", 400),
    (b"POST / HTTP/1.1\r\nContent-Length: 1001\r\n\r\n", 413),
    (b"POST / HTTP/1.1\r\n" + b"X: y\r\n" * 20 + b"Content-Length: 0\r\n\r\n", 431),
    (b"POST / HTTP/1.1\r\nX: " + b"a" * 600 + b"\r\n\r\n", 431),
    (b"POST / HTTP/1.1\r\nX: " + b"a" * 600, 431),  # no end of head in sight
])
def test_bad_framing_raises_the_status_to_answer(data, status):
    r = _request_reader(max_body_size=1000, max_header_size=512, max_header_count=10)
    with pytest.raises(H.HttpError) as e:
        _events(r, [data])
    assert e.value.status == status


def test_buffering_beyond_a_request_bound_is_refused():
    r = _request_reader(max_body_size=100, max_header_size=50)
    r.receive_data(b"x" * 150)
    with pytest.raises(H.HttpError) as e:
        r.receive_data(b"x")
    assert e.value.status == 413


def test_identical_heads_are_parsed_once_per_server():
    limits = H.RequestLimits()
    a, b = H.RequestReader(limits), H.RequestReader(limits)
    _events(a, [_req(b"one")])
    _events(b, [_req(b"two")])
    assert len(limits.heads) == 1


def test_a_server_that_asks_gets_get_requests_their_query_and_their_header_fields():
    page = _request_reader(methods=(b"GET", b"POST"), fields=True, cache=0)
    data = (b"GET /api/output?node=%2Fa HTTP/1.1\r\nHost: 127.0.0.1:8765\r\nX-Launcher-Token:  abc \r\n"
            b"Origin: http://127.0.0.1:8765\r\n\r\n" + _req(b"{}", path=b"/api/stop"))
    get, post = _events(page, [data])
    assert (get.method, get.target, get.query, get.body, get.keep_alive) == (b"GET", b"/api/output", b"node=%2Fa",
                                                                            b"", True)
    assert get.field(b"x-launcher-token") == b"abc" and get.field(b"host") == b"127.0.0.1:8765"
    assert get.field(b"cookie") is None
    assert (post.method, post.body, post.field(b"content-length")) == (b"POST", b"{}", b"2")
    assert page.limits.heads == {}  # (cache=0: none kept)
    # the XML-RPC servers' limits: POST alone, no fields kept
    with pytest.raises(H.HttpError) as e:
        _events(_request_reader(), [b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"])
    assert e.value.status == 501
    assert _events(_request_reader(), [_req(b"abc")])[0].fields == ()
    # a field name with a space before its colon is refused (RFC 9112 5.1), a GET may still say its length
    with pytest.raises(H.HttpError) as e:
        _events(_request_reader(methods=(b"GET",), fields=True), [b"GET / HTTP/1.1\r\nHost : x\r\n\r\n"])
    assert e.value.status == 400
    with_body = _events(_request_reader(methods=(b"GET",)), [b"GET / HTTP/1.1\r\nContent-Length: 2\r\n\r\nab"])
    assert with_body[0].body == b"ab"


# -- responses (the clients' side) -----------------------------------------------------

def _resp(body=b"<methodResponse/>", status=b"200 OK", extra=b""):
    return b"HTTP/1.1 %s\r\nContent-Length: %d\r\n%s\r\n" % (status, len(body), extra) + body


def _response(chunks, **kw):
    """Feed `chunks` (None: the server closes; empty chunks are skipped) until an event."""
    r = H.ResponseReader(**kw)
    for chunk in chunks:
        if chunk == b"":
            continue
        r.receive_data(b"" if chunk is None else chunk)
        ev = r.next_event()
        if ev is not H.NEED_DATA:
            return ev
    return r.next_event()


def test_response_split_at_every_position():
    data = _resp(b"<x/>")
    for cut in range(len(data) + 1):
        assert _response([data[:cut], data[cut:]]) == H.Response(200, b"<x/>"), cut


def test_response_without_length_ends_with_the_stream_and_interim_responses_are_skipped():
    data = b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.0 200 OK\r\nServer: x\r\n\r\n<body/>"
    for cut in range(len(data) + 1):
        assert _response([data[:cut], data[cut:], None]) == H.Response(200, b"<body/>"), cut


def test_error_status_is_an_event_not_an_error():
    assert _response([_resp(b"nope", b"404 Not Found")]) == H.Response(404, b"nope")


@pytest.mark.parametrize("chunks,message", [
    ([None], "without a reply"),
    ([b"HTTP/1.1 200 OK\r\nContent-Le", None], "before the reply was complete"),
    ([b"HTTP/1.1 200 OK\r\nContent-Length: 50\r\n\r\nabc", None], "before the reply was complete"),
    ([b"NOT HTTP\r\n\r\n"], "not an HTTP response"),
    ([b"HTTP/1.1 abc OK\r\n\r\n"], "not an HTTP response"),
    ([b"HTTP/1.1 200 OK\r\nContent-Length: 999999999\r\n\r\n"], "too large"),
    ([b"HTTP/1.1 200 OK\r\nContent-Length: 1\r\nContent-Length: 2\r\n\r\n"], "Content-Length"),
    ([b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n"], "not supported"),
    ([b"HTTP/1.1 200 OK\r\nX: " + b"a" * 70000], "header is too large"),
    ([b"HTTP/1.1 200 OK\r\n" + b"X: y\r\n" * 300 + b"\r\n"], "too many header lines"),
    ([b"HTTP/1.1 200 OK\r\n\r\n" + b"a" * 2000], "too large"),
])
def test_bad_responses_raise(chunks, message):
    with pytest.raises(H.HttpError, match=message):
        _response(chunks, max_body_size=1000)


def test_formatted_messages_read_back():
    req = H.format_request("/RPC2", "localhost:11311", b"<call/>")
    assert _events(_request_reader(), [req]) == [H.Request(b"/RPC2", b"<call/>", False)]
    for status, keep in ((200, True), (200, False), (404, True)):
        out = H.format_response(status, "Whatever", b"<r/>", keep)
        assert _response([out]) == H.Response(status, b"<r/>")
        assert (b"Connection: close" in out) is not keep


def test_module_imports_no_asyncio():
    import subprocess
    import sys
    code = "import sys, launcher.net.http; print('asyncio' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# ---------------------------------------------------------------------------
# URIs: split_uri reads them as urllib.parse.urlsplit does
# ---------------------------------------------------------------------------

from hypothesis import assume, given, settings, strategies as st  # noqa: E402
import sys  # noqa: E402
import urllib.parse  # noqa: E402

# (not the corners where urllib's rules changed since 3.8, where ours are 3.11's: a scheme that starts with a digit,
# a port with a sign or a space, an IPv6 zone's case)
_URI_PART = st.text(alphabet="hHtTpP:/[]@?#._0123456789aAzZ\t\n\x00", max_size=30)


@pytest.mark.skipif(sys.version_info < (3, 11), reason="urllib's rules before 3.11 differ in corners (`a:1` is a "
                    "path in 3.8); split_uri's are 3.11's, checked there")
@settings(max_examples=1500, deadline=None)
@given(st.one_of(_URI_PART, st.builds("{}://{}{}{}".format, st.sampled_from(["http", "HTTP", "h+1", ""]),
                                      st.sampled_from(["", "user@", "a:b@"]), _URI_PART, _URI_PART)))
def test_a_uri_is_split_as_urllib_splits_it(uri):
    assume(not uri.lstrip("\x00")[:1].isdigit())
    try:
        u = urllib.parse.urlsplit(uri)
        want = (u.scheme, u.netloc, u.hostname, u.port, u.path)
    except ValueError:
        want = None
    try:
        got = tuple(H.split_uri(uri))
    except ValueError:
        got = None
    if want is None and got is not None:
        assume("[" not in uri)  # (since 3.11.4 urllib checks a bracketed host is an IPv6 address: not done here)
    assert got == want


def test_the_uris_of_ros():
    assert H.split_uri("http://LocalHost:11311/") == ("http", "LocalHost:11311", "localhost", 11311, "/")
    assert H.split_uri("http://[::1]:8080") == ("http", "[::1]:8080", "::1", 8080, "")
    assert H.split_uri("http://h/RPC2?x#y") == ("http", "h", "h", None, "/RPC2")
    assert H.split_uri("http://[FE80::1%Eth0]:1/").hostname == "fe80::1%Eth0"  # (the zone keeps its case)
    for bad in ("http://h:notaport/", "http://h:70000/", "http://[::1/", "http://h:+1/"):
        with pytest.raises(ValueError):
            H.split_uri(bad)
