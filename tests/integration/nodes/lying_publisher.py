"""A ROS publisher that lies on TCPROS, for the hostile-peer tests: real sockets, registered on a real master.

    lying_publisher.py MODE TOPIC [__name:=NAME ...]

It registers as a publisher of TOPIC (std_msgs/String) with the master at ROS_MASTER_URI, serves the slave
API a subscriber calls (requestTopic) and a TCPROS port, and on each connection misbehaves as MODE says:

  error       an error header ("go away"), then closes
  wrongtype   a header with type "no type here" and md5sum "nonsense", then waits
  huge        a valid header, then a frame length of 2^31-1, then waits
  slowheader  a valid header, one byte a second
  garbage     a valid header, then text that is no frame
  midframe    a valid header, one message "m N", then 900 MB announced, 100 kB of it sent, and a close
  fast        a valid header, then 256 kB messages as fast as the socket takes them, for ever

Each TCPROS connection is a line "accept TIME" in $LIAR_LOG/MODE.log, and "eof TIME" once the subscriber closed
it. SIGUSR1 registers the publisher again (the master then sends its subscribers a publisherUpdate).
Only the standard library: any python runs it.
"""

import os
import signal
import socket
import struct
import sys
import threading
import time
import xmlrpc.client
from xmlrpc.server import SimpleXMLRPCServer

STRING = ("std_msgs/String", "992ce8a1687cec8c8bd883ec73ca41d1", "string data\n")

mode, topic = sys.argv[1], sys.argv[2]
name = next((a.split(":=", 1)[1] for a in sys.argv[3:] if a.startswith("__name:=")), "liar_" + mode)
callerid = "/" + name.lstrip("/")
log_path = os.path.join(os.environ["LIAR_LOG"], mode + ".log")
log_lock = threading.Lock()
sent = [0]  # messages of mode "fast" sent


def note(what):
    with log_lock, open(log_path, "a") as f:
        f.write("%s %.3f\n" % (what, time.time()))


def header(fields):
    items = [("%s=%s" % kv).encode() for kv in fields.items()]
    body = b"".join(struct.pack("<I", len(item)) + item for item in items)
    return struct.pack("<I", len(body)) + body


def valid_header():
    return header({"callerid": callerid, "topic": topic, "type": STRING[0], "md5sum": STRING[1],
                   "message_definition": STRING[2], "latching": "0"})


def message(text):
    data = text.encode() if isinstance(text, str) else text
    body = struct.pack("<I", len(data)) + data
    return struct.pack("<I", len(body)) + body


def read_header(conn):
    size = struct.unpack("<I", recv_exactly(conn, 4))[0]
    recv_exactly(conn, size)


def recv_exactly(conn, n):
    data = b""
    while len(data) < n:
        chunk = conn.recv(n - len(data))
        if not chunk:
            raise EOFError
        data += chunk
    return data


def wait_for_eof(conn):
    while conn.recv(65536):
        pass


def serve(conn, number):
    note("accept")
    try:
        read_header(conn)
        if mode == "error":
            conn.sendall(header({"error": "go away"}))
            return
        if mode == "wrongtype":
            conn.sendall(header({"callerid": callerid, "topic": topic, "type": "no type here", "md5sum": "nonsense"}))
        elif mode == "huge":
            conn.sendall(valid_header() + struct.pack("<I", 0x7FFFFFFF) + b"x" * 1000)
        elif mode == "slowheader":
            for byte in valid_header():
                conn.sendall(bytes([byte]))
                time.sleep(1.0)
        elif mode == "garbage":
            conn.sendall(valid_header() + b"GARBAGE! this is no TCPROS frame. " * 100)
        elif mode == "midframe":
            conn.sendall(valid_header() + message("m %d" % number) + struct.pack("<I", 900_000_000) + b"x" * 100_000)
            return
        elif mode == "fast":
            conn.sendall(valid_header())
            blob = os.urandom(256 << 10)
            while True:
                conn.sendall(message(b"%08d" % sent[0] + blob))
                sent[0] += 1
        wait_for_eof(conn)
        note("eof")
    except (EOFError, OSError):
        note("eof")
    finally:
        conn.close()


def tcpros_server():
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(16)

    def accept():
        number = 0
        while True:
            conn, _ = srv.accept()
            threading.Thread(target=serve, args=(conn, number), daemon=True).start()
            number += 1
    threading.Thread(target=accept, daemon=True).start()
    return srv.getsockname()[1]


def main():
    port = tcpros_server()
    api = SimpleXMLRPCServer(("127.0.0.1", 0), logRequests=False, allow_none=True)
    uri = "http://127.0.0.1:%d/" % api.server_address[1]
    api.register_function(lambda caller, t, protocols: [1, "ready", ["TCPROS", "127.0.0.1", port]], "requestTopic")
    api.register_function(lambda caller: [1, "", os.getpid()], "getPid")
    api.register_function(lambda caller, t, pubs: [1, "", 0], "publisherUpdate")
    api.register_function(lambda caller: [1, "", [[topic, STRING[0]]]], "getPublications")
    api.register_function(lambda caller: [1, "", []], "getSubscriptions")
    api.register_function(lambda caller: [1, "", []], "getBusInfo")
    api.register_function(lambda caller: [1, "", [[], [], [0, 0, 0]]], "getBusStats")
    api.register_function(lambda caller: [1, "", os.environ["ROS_MASTER_URI"]], "getMasterUri")
    api.register_function(lambda caller, msg="": (os.kill(os.getpid(), signal.SIGTERM), [1, "", 0])[1], "shutdown")
    threading.Thread(target=api.serve_forever, daemon=True).start()
    master = xmlrpc.client.ServerProxy(os.environ["ROS_MASTER_URI"])

    def register(*_):
        master.registerPublisher(callerid, topic, STRING[0], uri)
        note("register")
    register()
    signal.signal(signal.SIGUSR1, lambda *_: threading.Thread(target=register).start())
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    signal.signal(signal.SIGINT, lambda *_: sys.exit(0))
    while True:
        time.sleep(3600)


if __name__ == "__main__":
    main()
