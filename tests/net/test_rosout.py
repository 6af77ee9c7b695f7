"""rosout's line format, log rotation and settings, without a master."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import pytest

from launcher.net.rosout import (RosoutLogFile, decode_log, file_logging_disabled, format_log_line, format_stamp,
                                 rosout_typestore)

from helpers import ROOT, free_port, still_running, until


@pytest.fixture(scope="module")
def typestore():
    return rosout_typestore()  # what rosout runs with


def test_announced_log_type_is_rosbags_noetic_log():
    """/rosout is registered with constants (no rosbags at start): they are what rosbags computes."""
    from rosbags.typesys import Stores, get_typestore
    from launcher.net.rosout import LOG_DEFINITION, LOG_MD5
    assert get_typestore(Stores.ROS1_NOETIC).generate_msgdef("rosgraph_msgs/msg/Log") == (LOG_DEFINITION, LOG_MD5)


@pytest.mark.parametrize("name", ["rosgraph_msgs/msg/Log", "std_msgs/msg/Header", "roscpp/msg/Logger"])
def test_rosout_types_are_noetics(typestore, name):
    """rosout's small type store gives the same definitions and md5sums as rosbags' Noetic store."""
    from rosbags.typesys import Stores, get_typestore
    noetic = get_typestore(Stores.ROS1_NOETIC)
    assert typestore.generate_msgdef(name) == noetic.generate_msgdef(name)
    fields = "fielddefs" if hasattr(noetic, "fielddefs") else "FIELDDEFS"  # (rosbags 0.11's name; 0.9's)
    assert getattr(typestore, fields)[name] == getattr(noetic, fields)[name]


def _log(typestore, **fields):
    t = typestore.types
    values = dict(level=2, name="/talker_py", msg="hello info 1", file="pylog.py",
                  function="<module>", line=5, topics=["/chatter", "/rosout"])
    values.update(fields)
    stamp = t["builtin_interfaces/msg/Time"](sec=1795240437, nanosec=829590082)
    header = t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="")
    return t["rosgraph_msgs/msg/Log"](header=header, **values)


def test_line_is_the_reference_line(typestore):
    # This line was written by Debian's rosout for the same message from a rospy node.
    assert format_log_line(_log(typestore)) == (
        b"1795240437.829590082 INFO /talker_py [pylog.py:5(<module>)] "
        b"[topics: /chatter, /rosout] hello info 1\n")


@pytest.mark.parametrize("level, word", [(1, b"DEBUG"), (2, b"INFO"), (4, b"WARN"), (8, b"ERROR"),
                                         (16, b"FATAL"), (3, b"\x03"), (65, b"A")])
def test_levels_including_unknown_ones_printed_as_a_raw_byte(typestore, level, word):
    assert format_log_line(_log(typestore, level=level)).split(b" ")[1] == word


def test_omit_topics_and_empty_topics(typestore):
    assert format_log_line(_log(typestore), omit_topics=True) == (
        b"1795240437.829590082 INFO /talker_py [pylog.py:5(<module>)] hello info 1\n")
    assert b"[topics: ] hello" in format_log_line(_log(typestore, topics=[]))


def test_text_is_written_as_utf8_unchanged(typestore):
    line = format_log_line(_log(typestore, msg="température\tok\nsecond line"))
    assert line.endswith("température\tok\nsecond line\n".encode())


def test_stamp_pads_nanoseconds():
    assert format_stamp(12, 5) == "12.000000005"
    assert format_stamp(0, 0) == "0.000000000"


@pytest.mark.parametrize("value, disabled", [
    (None, False), ("", False), ("0", False), ("false", False), ("OFF", False), ("No", False),
    ("1", True), ("true", True), ("yes", True)])
def test_file_logging_switch(value, disabled):
    env = {} if value is None else {"ROSOUT_DISABLE_FILE_LOGGING": value}
    assert file_logging_disabled(env) is disabled


def test_startup_marker(tmp_path):
    f = RosoutLogFile(str(tmp_path / "run" / "rosout.log"))
    f.open()
    f.close()
    text = (tmp_path / "run" / "rosout.log").read_text()
    assert text.startswith("\n\n") and text.endswith("  Node Startup\n")
    float(text.split()[0])


def test_rotation_keeps_every_line_and_the_newest_backups(tmp_path):
    path = str(tmp_path / "rosout.log")
    f = RosoutLogFile(path, max_size=100, max_backups=3)
    f.open()
    lines = [b"line %04d %s\n" % (i, b"x" * 30) for i in range(40)]
    for line in lines:
        f.write(line)
    f.close()
    names = sorted(os.listdir(tmp_path))
    assert names == ["rosout.log", "rosout.log.1", "rosout.log.2", "rosout.log.3"]
    # Oldest backup first, then newer ones, then the live file: an unbroken tail of the lines.
    tail = b"".join(open(os.path.join(tmp_path, n), "rb").read()
                    for n in ["rosout.log.3", "rosout.log.2", "rosout.log.1", "rosout.log"])
    assert b"".join(lines).endswith(tail)
    assert len(tail) > 300 and f.lines == 40
    # A file rotates once it passes the limit, as rosout.cpp does (check after the write).
    for n in names[1:]:
        assert os.path.getsize(os.path.join(tmp_path, n)) > 100


EMPTY_MD5 = "d41d8cd98f00b204e9800998ecf8427e"  # md5 of nothing: an empty half of a service


def service_md5(typestore, request: str, response: str) -> str:
    """A service's md5sum: md5 over the request's then the response's md5 text (genmsg).

    rosbags gives the md5 of each half, not its text; when one half is empty the service md5 is
    the other half's md5, which covers roscpp's logger services. Other shapes are refused.
    """
    req = typestore.generate_msgdef(request)[1]
    resp = typestore.generate_msgdef(response)[1]
    if req == EMPTY_MD5:
        return resp
    if resp == EMPTY_MD5:
        return req
    raise NotImplementedError("service md5 of two non-empty halves (%s, %s)" % (request, response))


def test_logger_service_md5s_match_roscpp(typestore):
    from rosbags.typesys import get_types_from_msg
    from launcher.net.rosout import _LOGGER_SERVICE_TYPES
    types = {}
    for name, text in _LOGGER_SERVICE_TYPES.items():
        types.update(get_types_from_msg(text, name))
    typestore.register(types)
    # The values `rossrv md5 roscpp/GetLoggers` / `roscpp/SetLoggerLevel` print.
    assert service_md5(typestore, "roscpp/msg/GetLoggers_Request",
                       "roscpp/msg/GetLoggers_Response") == "32e97e85527d4678a8f9279894bb64b0"
    assert service_md5(typestore, "roscpp/msg/SetLoggerLevel_Request",
                       "roscpp/msg/SetLoggerLevel_Response") == "51da076440d78ca1684d36c868df61ea"
    with pytest.raises(NotImplementedError):
        service_md5(typestore, "roscpp/msg/SetLoggerLevel_Request", "roscpp/msg/Logger")
    # the constants rosout announces its services with
    from launcher.net.rosout import GET_LOGGERS_MD5, SET_LOGGER_LEVEL_MD5
    assert GET_LOGGERS_MD5 == service_md5(typestore, "roscpp/msg/GetLoggers_Request", "roscpp/msg/GetLoggers_Response")
    assert SET_LOGGER_LEVEL_MD5 == service_md5(typestore, "roscpp/msg/SetLoggerLevel_Request",
                                               "roscpp/msg/SetLoggerLevel_Response")


def test_text_that_is_not_utf8_is_kept_as_bytes(typestore):
    """roscpp may send any bytes; rosout.cpp writes them as they are, and so do we."""
    wire = bytes(typestore.serialize_ros1(_log(typestore, msg="h\u00e9llo", topics=["/t\u00e9"]),
                                          "rosgraph_msgs/msg/Log"))
    wire = wire.replace("h\u00e9llo".encode(), b"h\xff\xfello").replace("/t\u00e9".encode(), b"/t\xfe\xfe")
    with pytest.raises(Exception):
        typestore.deserialize_ros1(wire, "rosgraph_msgs/msg/Log")
    assert format_log_line(decode_log(wire)) == (b"1795240437.829590082 INFO /talker_py [pylog.py:5(<module>)] "
                                                 b"[topics: /t\xfe\xfe] h\xff\xfello\n")


@pytest.mark.parametrize("fields", [{}, {"topics": []}, {"msg": "", "name": "", "file": "", "function": ""},
                                    {"msg": "temp\u00e9rature\n" * 1000, "level": 16, "line": 2 ** 32 - 1},
                                    {"topics": ["/a", "/b\u00e9", "/c" * 300]}])
def test_decode_log_reads_what_rosbags_writes(typestore, fields):
    """Our Log decoder against rosbags' serializer: every field, as rosbags reads it back."""
    msg = _log(typestore, **fields)
    msg.header.frame_id = "a frame"
    msg.header.seq = 77
    wire = bytes(typestore.serialize_ros1(msg, "rosgraph_msgs/msg/Log"))
    ours = decode_log(wire)
    theirs = typestore.deserialize_ros1(wire, "rosgraph_msgs/msg/Log")
    assert (ours.header.seq, ours.header.stamp.sec, ours.header.stamp.nanosec, ours.header.frame_id) == (
        theirs.header.seq, theirs.header.stamp.sec, theirs.header.stamp.nanosec, theirs.header.frame_id)
    for field in ("level", "name", "msg", "file", "function", "line", "topics"):
        assert getattr(ours, field) == getattr(theirs, field), field
    assert format_log_line(ours) == format_log_line(theirs)


def test_a_truncated_log_is_refused_not_misread(typestore):
    wire = bytes(typestore.serialize_ros1(_log(typestore), "rosgraph_msgs/msg/Log"))
    for cut in range(len(wire)):
        with pytest.raises(ValueError):
            decode_log(wire[:cut])
    wire = bytes(typestore.serialize_ros1(_log(typestore, topics=[]), "rosgraph_msgs/msg/Log"))
    huge = wire[:-4] + (2 ** 31).to_bytes(4, "little")  # the topic count claims 2 G topics
    with pytest.raises(ValueError):
        decode_log(huge)


def test_a_failing_disk_is_reported_once_and_writing_resumes(tmp_path, caplog):
    f = RosoutLogFile(str(tmp_path / "rosout.log"))
    f.open()

    class Full:
        def write(self, data):
            raise OSError(28, "No space left on device")

    good, f.handle = f.handle, Full()
    with caplog.at_level("ERROR", logger="launcher.rosout"):
        f.write(b"lost 1\n")
        f.write(b"lost 2\n")
    assert [r.getMessage().count("No space left") for r in caplog.records] == [1]
    f.handle = good
    f.write(b"kept\n")
    f.close()
    assert (tmp_path / "rosout.log").read_bytes().endswith(b"Node Startup\nkept\n")
    assert f.lines == 1


def test_rosout_writes_its_lines_without_rosbags(tmp_path, typestore):
    """rosout.log's lines need no rosbags (nor numpy): an interpreter that lacks it (Debian's python
    running `python3 -m launcher`) still gets them, and a plain launch does not pay for its import."""
    wire = bytes(typestore.serialize_ros1(_log(typestore), "rosgraph_msgs/msg/Log"))
    code = ("import sys; sys.modules['rosbags'] = sys.modules['numpy'] = None\n"
            "from launcher.net.rosout import decode_log, format_log_line\n"
            "sys.stdout.buffer.write(format_log_line(decode_log(bytes.fromhex(sys.argv[1]))))")
    out = subprocess.run([sys.executable, "-c", code, wire.hex()], env=dict(os.environ, PYTHONPATH=ROOT),
                         capture_output=True, check=True).stdout
    assert out == format_log_line(_log(typestore))


def test_a_serialized_logs_level_is_read_without_decoding_it(typestore):
    from launcher.net.rosout import peek_level
    for level in (1, 2, 4, 8, 16):
        msg = _log(typestore, level=level)
        msg.header.frame_id = "a frame id"
        assert peek_level(bytes(typestore.serialize_ros1(msg, "rosgraph_msgs/msg/Log"))) == level
    assert peek_level(b"") == 0
