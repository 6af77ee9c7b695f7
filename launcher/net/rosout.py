"""The built-in rosout node: collects /rosout into rosout.log and republishes it on /rosout_agg."""

from __future__ import annotations

import asyncio
import logging
import os
import struct
import time
from collections.abc import Callable, Mapping
from typing import Any, BinaryIO, NamedTuple

from launcher.net.slave import SlaveNode, default_host
from launcher.net.publisher_link import PublisherLink
from launcher.net.service import ServiceServer
from launcher.net.tcpros import TopicType

log = logging.getLogger("launcher.rosout")

LOG_TYPE = "rosgraph_msgs/Log"
# rosout.cpp's defaults: rotate at 100 MB, keep rosout.log.1 .. rosout.log.10.
MAX_FILE_SIZE = 100 * 1024 * 1024
MAX_BACKUPS = 10

_LEVEL_NAMES = {1: b"DEBUG", 2: b"INFO", 4: b"WARN", 8: b"ERROR", 16: b"FATAL"}
WARN = 4  # rosgraph_msgs/Log's level: this and above (ERROR, FATAL) go to warning_listeners

# The only messages rosout speaks, as in their .msg files: the type store is built from these
# alone (~3 ms) rather than from rosbags' whole Noetic store (~100 ms at every launch's start).
# Same text, same md5sums and definitions (tests/net/test_rosout.py checks against the Noetic store).
_ROSOUT_MSG_TYPES = {
    "std_msgs/msg/Header": "uint32 seq\ntime stamp\nstring frame_id",
    "rosgraph_msgs/msg/Log": "byte DEBUG=1\nbyte INFO=2\nbyte WARN=4\nbyte ERROR=8\nbyte FATAL=16\n"
                             "Header header\nbyte level\nstring name\nstring msg\nstring file\n"
                             "string function\nuint32 line\nstring[] topics",
    "roscpp/msg/Logger": "string name\nstring level",
}
# What rosout announces at registration, as rosbags computes it from the definitions above
# (tests/net/test_rosout.py checks): constants, so that registering /rosout needs no type store and
# rosbags is not imported before the nodes are spawned.
LOG_MD5 = "acffd30cd6b6de30f120938c17c593fb"
LOG_DEFINITION = (
    "byte DEBUG=1\nbyte INFO=2\nbyte WARN=4\nbyte ERROR=8\nbyte FATAL=16\nstd_msgs/Header header\n"
    "byte level\nstring name\nstring msg\nstring file\nstring function\nuint32 line\nstring[] topics\n"
    + "=" * 80 + "\nMSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n")
GET_LOGGERS_MD5 = "32e97e85527d4678a8f9279894bb64b0"  # `rossrv md5 roscpp/GetLoggers`
SET_LOGGER_LEVEL_MD5 = "51da076440d78ca1684d36c868df61ea"  # `rossrv md5 roscpp/SetLoggerLevel`
# Every roscpp node (rosout.cpp included) serves ~get_loggers and ~set_logger_level; these are
# their request/response definitions (roscpp/srv/*.srv), which rosbags' type store lacks.
_LOGGER_SERVICE_TYPES = {
    "roscpp/msg/GetLoggers_Request": "",
    "roscpp/msg/GetLoggers_Response": "roscpp/Logger[] loggers",
    "roscpp/msg/SetLoggerLevel_Request": "string logger\nstring level",
    "roscpp/msg/SetLoggerLevel_Response": "",
}
# What our Python loggers are called in roscpp's level words, and back.
_PY_TO_ROS_LEVEL = {logging.DEBUG: "debug", logging.INFO: "info", logging.WARNING: "warn",
                    logging.ERROR: "error", logging.CRITICAL: "fatal"}
_ROS_TO_PY_LEVEL = {v: k for k, v in _PY_TO_ROS_LEVEL.items()}
# The loggers this node's get_loggers reports and set_logger_level may change.
_OWN_LOGGERS = ("launcher.rosout", "launcher.slave", "launcher.tcpros")


def format_stamp(sec: int, nsec: int) -> str:
    """A ros::Time as roscpp prints it: seconds, a dot, nanoseconds padded to nine digits."""
    return "%d.%09d" % (sec, nsec)


def _bytes(value: Any) -> bytes:
    # A str of a UTF-8 Log, or the bytes of one that is not (decode_log).
    return value.encode("utf-8") if isinstance(value, str) else bytes(value)


_LEVEL_TEXT = {k: v.decode() for k, v in _LEVEL_NAMES.items()}


def peek_level(payload: bytes) -> int:
    """A serialized Log's level without decoding it: after the header's seq, stamp and frame_id."""
    at = 16 + int.from_bytes(payload[12:16], "little")
    return payload[at] if len(payload) > at else 0


class Stamp(NamedTuple):
    sec: int
    nanosec: int  # (rosbags' name: what format_log_line reads of a message from either)


class Header(NamedTuple):
    seq: int
    stamp: Stamp
    frame_id: Any


class LogMessage(NamedTuple):
    """A decoded rosgraph_msgs/Log: its strings str, or all bytes when any is not UTF-8."""
    header: Header
    level: int
    name: Any
    msg: Any
    file: Any
    function: Any
    line: int
    topics: list


_U32 = struct.Struct("<I")
_HEAD = struct.Struct("<III")  # header.seq, stamp.secs, stamp.nsecs


def _sized(view: memoryview, at: int, what: str) -> tuple[bytes, int]:
    """The length-prefixed bytes at `at` (a string of the message), and where the next field begins."""
    n, = _U32.unpack_from(view, at)
    at += 4
    if at + n > len(view):
        raise ValueError("%s runs past the message's end" % what)
    return bytes(view[at:at + n]), at + n


def decode_log(payload: bytes) -> LogMessage:
    """A serialized rosgraph_msgs/Log, decoded; ValueError if it is not one.

    By hand rather than by rosbags: its type store and deserializer import numpy and cost ~10 MB
    and ~0.1 s of CPU at every launch's start, for one fixed message of strings. roscpp may send
    text that is not UTF-8; rosout.cpp writes it as it is, so such a message keeps its bytes.
    """
    view = memoryview(payload)
    try:
        seq, sec, nsec = _HEAD.unpack_from(view, 0)
        at = 12
        strings = []
        for i in range(6):  # frame_id; then level; name, msg, file, function
            if i == 1:
                strings.append(view[at])
                at += 1
                continue
            text, at = _sized(view, at, "a string")
            strings.append(text)
        line, count = struct.unpack_from("<II", view, at)
        at += 8
        if count > len(view) - at:
            raise ValueError("more topics than bytes")
        topics = []
        for _ in range(count):
            topic, at = _sized(view, at, "a topic")
            topics.append(topic)
    except (struct.error, IndexError) as exc:
        raise ValueError("truncated rosgraph_msgs/Log (%s)" % exc) from None
    frame_id, level, name, msg, file, function = strings
    try:
        text = [s.decode("utf-8") for s in (frame_id, name, msg, file, function, *topics)]
        frame_id, name, msg, file, function = text[:5]
        topics = text[5:]
    except UnicodeDecodeError:
        pass  # (all kept as bytes)
    return LogMessage(Header(seq, Stamp(sec, nsec), frame_id), level, name, msg, file, function, line, topics)


def _text(value: Any) -> str:
    return value if isinstance(value, str) else _bytes(value).decode("utf-8", "replace")


def format_log_line(msg: Any, omit_topics: bool = False) -> bytes:
    """One rosout.log line for a rosgraph_msgs/Log, byte for byte as rosout.cpp writes it."""
    level_text = _LEVEL_TEXT.get(msg.level)
    if level_text is not None and isinstance(msg.msg, str):
        # The common case (known level, text as str), in one formatting step: this runs for
        # every message, thousands per second.
        stamp = msg.header.stamp
        if omit_topics:
            return ("%d.%09d %s %s [%s:%d(%s)] %s\n" % (
                stamp.sec, stamp.nanosec, level_text, msg.name, msg.file, msg.line,
                msg.function, msg.msg)).encode("utf-8")
        return ("%d.%09d %s %s [%s:%d(%s)] [topics: %s] %s\n" % (
            stamp.sec, stamp.nanosec, level_text, msg.name, msg.file, msg.line, msg.function,
            ", ".join(msg.topics), msg.msg)).encode("utf-8")
    stamp = msg.header.stamp
    # rosout.cpp streams an unknown level as the raw uint8_t, i.e. as one byte.
    level = _LEVEL_NAMES.get(msg.level) or bytes([msg.level & 0xFF])
    parts = [format_stamp(stamp.sec, stamp.nanosec).encode(), b" ", level, b" ",
             _bytes(msg.name), b" [", _bytes(msg.file), b":", str(msg.line).encode(), b"(",
             _bytes(msg.function), b")] "]
    if not omit_topics:
        topics = [_bytes(t) for t in msg.topics]
        parts += [b"[topics: ", b", ".join(topics), b"] "]
    parts += [_bytes(msg.msg), b"\n"]
    return b"".join(parts)


def rosout_typestore() -> Any:
    """A rosbags type store holding just what rosout reads, writes and serves."""
    # rosbags is heavy: imported only when rosout runs, not on every `launch`.
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    typestore = get_typestore(Stores.EMPTY)  # builtin time/duration only
    types: dict[str, Any] = {}
    for name, text in {**_ROSOUT_MSG_TYPES, **_LOGGER_SERVICE_TYPES}.items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)
    return typestore


def _logger_level(name: str) -> str:
    level = logging.getLogger(name).getEffectiveLevel()
    for py_level in sorted(_PY_TO_ROS_LEVEL, reverse=True):
        if level >= py_level:
            return _PY_TO_ROS_LEVEL[py_level]
    return "debug"


def file_logging_disabled(environ: Mapping[str, str]) -> bool:
    """ROSOUT_DISABLE_FILE_LOGGING, read as rosout.cpp reads it."""
    value = environ.get("ROSOUT_DISABLE_FILE_LOGGING", "").lower()
    return value not in ("", "0", "false", "off", "no")


class RosoutLogFile:
    """rosout.log with rosout.cpp's size-based rotation into rosout.log.1 .. rosout.log.N."""

    def __init__(self, path: str, *, max_size: int = MAX_FILE_SIZE, max_backups: int = MAX_BACKUPS):
        self.path = path
        self.max_size = max_size
        self.max_backups = max_backups
        self.size = 0
        self.backups = 0
        self.lines = 0
        self.failing = False
        self.handle: BinaryIO | None = None

    def open(self) -> None:
        os.makedirs(os.path.dirname(self.path) or ".", exist_ok=True)
        self.handle = open(self.path, "wb")
        now = time.time_ns()
        self.write(b"\n\n%s  Node Startup\n" % format_stamp(now // 10**9, now % 10**9).encode(),
                   counted=False)
        self.flush()

    def write(self, line: bytes, *, counted: bool = True) -> None:
        if self.handle is None:
            return
        try:
            self.handle.write(line)
        except OSError as exc:
            self._report(exc, "writing to")
            return
        self.failing = False
        self.size += len(line)
        if counted:
            self.lines += 1
        if self.size > self.max_size:
            self.rotate()

    def _report(self, exc: OSError, doing: str) -> None:
        # Like rosout.cpp, carry on after a failed write (a full disk may free up), but say so
        # once per run of failures rather than once per message.
        if not self.failing:
            log.error("Error %s rosout log file '%s': %s", doing, self.path, exc)
        self.failing = True

    def rotate(self) -> None:
        """Shift rosout.log -> .1 -> .2 ..., dropping the oldest, and start an empty rosout.log."""
        log.info("rosout log file %s reached max size, rotating log files", self.path)
        assert self.handle is not None
        try:
            self.handle.close()
        except OSError as exc:
            self._report(exc, "closing")
        self.handle = None
        if self.backups == self.max_backups:
            try:
                os.remove("%s.%d" % (self.path, self.max_backups))
            except OSError as exc:
                log.error("deleting the oldest rosout log file: %s", exc)
        for i in range(min(self.max_backups, self.backups + 1), 0, -1):
            src = self.path if i == 1 else "%s.%d" % (self.path, i - 1)
            try:
                os.rename(src, "%s.%d" % (self.path, i))
            except OSError as exc:
                log.error("rotating rosout log file %s: %s", src, exc)
        self.backups = min(self.backups + 1, self.max_backups)
        self.size = 0
        try:
            self.handle = open(self.path, "wb")
        except OSError as exc:  # as rosout.cpp: no file from here on, but keep republishing
            log.error("Error opening rosout log file '%s': %s", self.path, exc)

    def flush(self) -> None:
        if self.handle is not None:
            try:
                self.handle.flush()
            except OSError as exc:
                self._report(exc, "flushing")

    def close(self) -> None:
        if self.handle is not None:
            try:
                self.handle.flush()
                os.fsync(self.handle.fileno())
            except OSError as exc:
                self._report(exc, "flushing")
            finally:
                try:
                    self.handle.close()
                except OSError:
                    pass  # the error was reported above; the data that could be kept is kept
                self.handle = None


class Rosout:
    """The `/rosout` node, in-process on the caller's asyncio loop."""

    def __init__(self, master_uri: str, log_dir: str, *, host: str | None = None,
                 environ: Mapping[str, str] | None = None, max_file_size: int = MAX_FILE_SIZE,
                 max_backups: int = MAX_BACKUPS, name: str = "/rosout",
                 in_process: dict[str, Callable[[str, list], Any]] | None = None):
        """`in_process`: a master of this process's `in_process_apis` (net.slave.SlaveNode)."""
        self.master_uri = master_uri
        self.in_process = in_process
        self.log_dir = log_dir
        self.host = host
        self.name = name
        self.environ = os.environ if environ is None else environ
        self.file: RosoutLogFile | None = None
        if not file_logging_disabled(self.environ):
            self.file = RosoutLogFile(os.path.join(log_dir, "rosout.log"),
                                      max_size=max_file_size, max_backups=max_backups)
        self.omit_topics = False
        self.received = 0
        self.undecodable = 0
        self.node: Any = None
        self._typestore: Any = None
        self._typestore_error: BaseException | None = None  # why no type store can be built (rosbags missing)
        self._agg: Any = None
        self._flush_pending = False
        self._watch: asyncio.Task | None = None
        # called with (level, node name, text) of each WARN, ERROR or FATAL message (the live views' tail)
        self.warning_listeners: list[Callable[[int, str, str], None]] = []

    @property
    def log_path(self) -> str | None:
        return self.file.path if self.file is not None else None

    async def start(self) -> None:
        """Open rosout.log, then register /rosout: publish /rosout_agg, subscribe /rosout."""
        mtype = TopicType(LOG_TYPE, LOG_MD5, LOG_DEFINITION)
        if self.file is not None:
            try:
                self.file.open()
            except OSError as exc:
                log.error("Error opening rosout log file '%s': %s", self.file.path, exc)
                self.file = None
        await self._start_node(mtype)

    def _unusable(self, exc: BaseException) -> None:
        if self._typestore_error is None:
            self._typestore_error = exc
            log.error("rosout cannot serve its logger services (rosbags: %s)", exc)

    def _types(self) -> Any:
        """The type store of the logger services, built at their first call (rosbags is heavy, and
        rarely asked for: rqt_logger_level, rosnode); raises what building it raised."""
        if self._typestore is not None:
            return self._typestore
        if self._typestore_error is not None:
            raise self._typestore_error
        try:
            self._typestore = rosout_typestore()
            return self._typestore
        except Exception as exc:
            self._unusable(exc)
            raise

    async def _start_node(self, mtype: TopicType) -> None:
        self.node = SlaveNode(self.name, self.master_uri,
                              host=self.host or default_host(self.environ), in_process=self.in_process)
        await self.node.start()
        try:
            self._agg = await self.node.advertise("/rosout_agg", mtype)
            value = await self.node.subscribe_param("/rosout/omit_topics", self._set_omit_topics)
            self._set_omit_topics(value)
            await self.node.subscribe("/rosout", mtype, self._on_log)
            for service in self._logger_services():
                await self.node.advertise_service(service)
        except BaseException:
            await self.node.stop()
            raise
        self._watch = asyncio.get_running_loop().create_task(self._respawn_on_shutdown(mtype))

    async def _respawn_on_shutdown(self, mtype: TopicType) -> None:
        # roscore runs rosout with respawn="true": `rosnode kill /rosout` gets a fresh one.
        await self.node.shutdown_requested.wait()
        log.info("/rosout was asked to shut down (%s); restarting it", self.node.shutdown_reason)
        old, self._watch = self.node, None
        try:
            await old.stop()
            await self._start_node(mtype)
        except Exception as exc:  # a background task: report, never raise into the void
            log.error("could not restart /rosout: %s", exc)

    def _logger_services(self) -> list[ServiceServer]:
        def get_loggers(request: bytes) -> bytes:
            ts = self._types()
            logger_t = ts.types["roscpp/msg/Logger"]
            loggers = [logger_t(name=n, level=_logger_level(n)) for n in _OWN_LOGGERS]
            return bytes(ts.serialize_ros1(ts.types["roscpp/msg/GetLoggers_Response"](
                loggers=loggers), "roscpp/msg/GetLoggers_Response"))

        def set_logger_level(request: bytes) -> bytes:
            ts = self._types()
            req = ts.deserialize_ros1(request, "roscpp/msg/SetLoggerLevel_Request")
            level = _ROS_TO_PY_LEVEL.get(req.level.lower())
            if req.logger not in _OWN_LOGGERS or level is None:
                raise ValueError("no logger [%s] or no level [%s]" % (req.logger, req.level))
            logging.getLogger(req.logger).setLevel(level)
            return b""

        return [
            ServiceServer(self.name + "/get_loggers", "roscpp/GetLoggers",
                          GET_LOGGERS_MD5,
                          "roscpp/GetLoggersRequest", "roscpp/GetLoggersResponse",
                          self.name, get_loggers),
            ServiceServer(self.name + "/set_logger_level", "roscpp/SetLoggerLevel",
                          SET_LOGGER_LEVEL_MD5,
                          "roscpp/SetLoggerLevelRequest", "roscpp/SetLoggerLevelResponse",
                          self.name, set_logger_level),
        ]

    def _set_omit_topics(self, value: Any) -> None:
        # roscpp's getParamCached only takes a bool; anything else leaves the flag as it was.
        if isinstance(value, bool):
            self.omit_topics = value
        elif value == {}:
            self.omit_topics = False

    def _on_log(self, payload: bytes, link: PublisherLink) -> None:
        self.received += 1
        self._agg.publish(payload)
        if self.file is None and (not self.warning_listeners or peek_level(payload) < WARN):
            return  # (nothing to decode it for)
        try:
            msg = decode_log(payload)
        except ValueError as exc:
            self.undecodable += 1
            log.warning("undecodable rosgraph_msgs/Log from %s: %s", link.publisher_uri, exc)
            return
        if msg.level >= WARN and self.warning_listeners:
            name, text = _text(msg.name), _text(msg.msg)
            for listener in self.warning_listeners:
                listener(msg.level, name, text)
        if self.file is None:
            return
        self.file.write(format_log_line(msg, self.omit_topics))
        if not self._flush_pending:
            # One flush per burst of messages, not per line: same durability as rosout.cpp's
            # fflush (the data reaches the OS) at a fraction of the system calls.
            self._flush_pending = True
            asyncio.get_running_loop().call_soon(self._flush)

    def _flush(self) -> None:
        self._flush_pending = False
        if self.file is not None:
            self.file.flush()

    async def stop(self) -> None:
        """Take in what publishers already sent, unregister, and flush+fsync rosout.log."""
        if self._watch is not None:
            self._watch.cancel()
            self._watch = None
        try:
            if self.node is not None:
                await self.node.stop()
        finally:
            if self.file is not None:
                self.file.close()
