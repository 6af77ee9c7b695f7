"""The bag fuzz (issue 37): seeded mutants of bags written by rosbags and by Debian's rosbag (uncompressed, bz2, lz4)
of each kind the hostile-input round used, given to `launcher bag info`, `launcher bag play -i -q` (and reindex)
under a 2 GiB address-space limit and 10 s each: no traceback, no internal error, no run over 10 s, and each failing
run's last line names the bag and says what was wrong; a test per kind checks the words; every bag truncated after
its header is reindexed into a readable bag, holding every message of the chunks before the cut."""

from __future__ import annotations

import json
import os
import random
import resource
import subprocess
import sys
import xmlrpc.client
from typing import NamedTuple

import pytest
from rosbags.rosbag1 import Reader, Writer

import bagmutants
from bagmutants import KINDS, MAGIC, U32, mutant, records
from helpers import ROOT, ROS_PATH, ROS_PYTHON, free_port, until

from launcher.bag import reindex
from launcher.bag.reader import Bag

HERE = os.path.dirname(os.path.abspath(__file__))
SEED = 37
# mutants of each base bag, by kind: 6 base bags x 25 = 150 mutants, 600 runs of info, info -y --freq, play and
# reindex
PER_KIND = {"truncated": 5, "flipped": 6, "field4": 6, "bag_header": 3, "compression": 2, "header_length": 3}
ADDRESS_SPACE = 2 << 30
LIMIT_S = 10.0
COUNT = 240
PLAY = ["play", "-i", "-q", "-d", "0"]  # (-d 0: the wait after advertising is no part of reading the bag)


def string(text: str) -> bytes:
    data = text.encode()
    return len(data).to_bytes(4, "little") + data


def rosbags_bag(path: str, compression: str) -> None:
    """Two topics, three connections (one topic from two callers), many small chunks."""
    writer = Writer(path)
    if compression != "none":
        writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    writer.chunk_threshold = 1024
    writer.open()
    conns = [writer.add_connection("/chatter", "std_msgs/msg/String", msgdef="string data\n",
                                   md5sum="992ce8a1687cec8c8bd883ec73ca41d1", callerid=caller, latching=0)
             for caller in ("/a", "/b")]
    conns.append(writer.add_connection("/count", "std_msgs/msg/Int32", msgdef="int32 data\n",
                                       md5sum="da5909fbe378aeaf85e547e830cc1bb7", callerid="/c", latching=1))
    for n in range(COUNT):
        stamp = 1_700_000_000_000_000_000 + n * 10_000_000
        if n % 4 == 3:
            writer.write(conns[2], stamp, n.to_bytes(4, "little"))
        else:
            writer.write(conns[n % 2], stamp, string("hello %d " % n * 3))
    writer.close()


# Debian's rosbag writing the same kind of bag, one per compression.
_DEBIAN = r"""
import sys, rosbag, rospy
from std_msgs.msg import String, Int32
for kind in ("none", "bz2", "lz4"):
    with rosbag.Bag("%s/debian-%s.bag" % (sys.argv[1], kind), "w", compression=kind, chunk_threshold=1024) as bag:
        for n in range(int(sys.argv[2])):
            t = rospy.Time(1700000000, 0) + rospy.Duration(0, n * 10000000)
            if n % 4 == 3:
                bag.write("/count", Int32(n), t)
            else:
                bag.write("/chatter", String("hello %d " % n * 3), t)
"""


def debian_rosbag_missing() -> str | None:
    try:
        subprocess.run([ROS_PYTHON, "-c", "import rosbag"], check=True, capture_output=True, timeout=60,
                       env=dict(os.environ, PATH=ROS_PATH, PYTHONPATH=""))
    except (OSError, subprocess.SubprocessError):
        return "Debian's rosbag (python3-rosbag) does not import under %s" % ROS_PYTHON
    return None


@pytest.fixture(scope="module")
def base_bags(tmp_path_factory, request) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("base")
    bags = {}
    for kind in ("none", "bz2", "lz4"):
        bags["rosbags-" + kind] = str(folder / ("rosbags-%s.bag" % kind))
        rosbags_bag(bags["rosbags-" + kind], kind)
    why = debian_rosbag_missing()
    if why:
        request.getfixturevalue("ros_part_missing")(why)  # (a failure under REQUIRE_ROS=1)
    made = subprocess.run([ROS_PYTHON, "-c", _DEBIAN, str(folder), str(COUNT)], capture_output=True, text=True,
                          timeout=120, env=dict(os.environ, PATH=ROS_PATH, PYTHONPATH=""))
    assert made.returncode == 0, made.stderr
    for kind in ("none", "bz2", "lz4"):
        bags["debian-" + kind] = str(folder / ("debian-%s.bag" % kind))
    return bags


@pytest.fixture(scope="module")
def master(tmp_path_factory):
    """Our `launch --core` for play's node to register with."""
    home = tmp_path_factory.mktemp("master")
    port = free_port()
    uri = "http://127.0.0.1:%d/" % port
    env = dict(os.environ, ROS_HOME=str(home), ROS_LOG_DIR=str(home / "log"), ROS_MASTER_URI=uri)
    proc = subprocess.Popen([sys.executable, "-m", "launcher", "--core", "-p", str(port)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        until(lambda: xmlrpc.client.ServerProxy(uri).getPid("/t")[0] == 1, 30, what="launch --core",
              errors=(OSError, xmlrpc.client.Error))
        yield dict(env, ROS_IP="127.0.0.1")
    finally:
        proc.terminate()
        proc.wait(30)


def limit_address_space() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))


def run_bag(jobs: list[list[str]], env: dict[str, str], tmp_path) -> list[dict]:
    """Each argv of `launcher bag`, run in one worker process under the address-space limit (fuzzworker.py)."""
    tag = "%d" % len(os.listdir(str(tmp_path)))
    jobs_file, results_file = str(tmp_path / ("jobs%s.json" % tag)), str(tmp_path / ("results%s.json" % tag))
    with open(jobs_file, "w") as f:
        json.dump(jobs, f)
    worker = subprocess.run([sys.executable, os.path.join(HERE, "fuzzworker.py"), jobs_file, results_file],
                            env=dict(env, PYTHONPATH=ROOT), preexec_fn=limit_address_space, capture_output=True,
                            text=True, timeout=60 + len(jobs) * LIMIT_S)
    assert worker.returncode == 0, worker.stderr
    with open(results_file) as f:
        return json.load(f)


def problems_of(result: dict, path: str) -> list[str]:
    """What is wrong with one run: a traceback, an internal error, a run over 10 s, a failure without a last line
    naming the bag and what was wrong."""
    argv = " ".join(result["argv"][:1] + result["argv"][-1:])
    if result["exception"]:
        return ["%s: %s" % (argv, result["exception"])]
    out = []
    err = result["err"]
    if result["seconds"] > LIMIT_S:
        out.append("%s: %.1f s" % (argv, result["seconds"]))
    for word in ("Traceback", "never retrieved", "Exception in callback", "Error in", "Unhandled"):
        if word in err:
            out.append("%s: %r in its stderr:\n%s" % (argv, word, err))
    if result["code"] not in (0, 1):
        out.append("%s: exit status %r\n%s" % (argv, result["code"], err))
    if result["code"] == 1:
        last = err.strip().splitlines()[-1] if err.strip() else ""
        prefix = "ERROR %s: " % path
        if not last.startswith(prefix) or len(last) < len(prefix) + 10:
            out.append("%s: its last line does not name the bag and what was wrong: %r" % (argv, last))
    return out


def make_mutants(base_bags: dict[str, str], folder) -> list[tuple[str, str, str]]:
    """(kind, what was done, path) of each mutant, the same ones on every run (seeded)."""
    rnd = random.Random(SEED)
    out = []
    for name, path in sorted(base_bags.items()):
        with open(path, "rb") as f:
            data = f.read()
        for kind in KINDS:
            for n in range(PER_KIND[kind]):
                broken, what = mutant(data, kind, rnd)
                target = str(folder / ("%s-%s-%d.bag" % (name, kind, n)))
                with open(target, "wb") as f:
                    f.write(broken)
                out.append((kind, "%s: %s" % (name, what), target))
    return out


def test_fuzz_info_and_play(base_bags, master, tmp_path):
    folder = tmp_path / "mutants"
    folder.mkdir()
    mutants = make_mutants(base_bags, folder)
    reindexed = tmp_path / "reindexed"
    reindexed.mkdir()
    commands = [["info"], ["info", "-y", "--freq"], PLAY, ["reindex", "--output-dir", str(reindexed)]]
    jobs = [argv + [path] for _, _, path in mutants for argv in commands]
    results = run_bag(jobs, master, tmp_path)
    problems = []
    failed = warned = 0
    for (kind, what, path), runs in zip(mutants, zip(*(results[i::len(commands)] for i in range(len(commands))))):
        for result in runs:
            problems += ["%s (%s): %s" % (kind, what, p) for p in problems_of(result, path)]
            failed += result["code"] == 1
            warned += result["code"] == 0 and "[ WARN]" in result["err"]
        if runs[-1]["code"] == 0:  # what reindex wrote: a whole bag, to us and to rosbags
            fixed = str(reindexed / os.path.basename(path))
            with Bag(fixed) as bag:
                ours = sum(1 for _ in bag.messages(warn=problems.append))
                problems += bag.warnings()
            with Reader(fixed) as reader:
                if sum(1 for _ in reader.messages()) != ours:
                    problems.append("%s: rosbags reads another number of messages than %d" % (fixed, ours))
    print("bag fuzz: %d mutants, %d runs: %d failed cleanly, %d ran with a warning, %d ran clean; %.1f s"
          % (len(mutants), len(results), failed, warned, len(results) - failed - warned,
             sum(r["seconds"] for r in results)))
    assert not problems, "\n".join(problems)
    # the fuzz reaches the damage it means to: most runs meet it
    assert failed + warned > len(results) // 2


def test_truncated_bags_reindex_into_readable_bags(base_bags, tmp_path):
    """Every bag cut after its header: reindexed, it holds every message of each chunk that ends before the cut."""
    rnd = random.Random(SEED)
    cuts = []
    for name, path in sorted(base_bags.items()):
        with open(path, "rb") as f:
            data = f.read()
        for n in range(5):
            cut = rnd.randrange(bagmutants.header_end(data), len(data))
            target = str(tmp_path / ("%s-cut%d.bag" % (name, n)))
            with open(target, "wb") as f:
                f.write(data[:cut])
            cuts.append((path, cut, target))
    out = tmp_path / "reindexed"
    out.mkdir()
    results = run_bag([["reindex", "--output-dir", str(out), target] for _, _, target in cuts], os.environ, tmp_path)
    for (path, cut, target), result in zip(cuts, results):
        assert not result["exception"] and result["code"] == 0, result
        with open(path, "rb") as f:
            stamps = kept_stamps(f.read(), cut)
        with Reader(path) as reader:  # the original, by rosbags: what each chunk before the cut holds
            kept = [(c.topic, t, bytes(d)) for c, t, d in reader.messages() if t in stamps]
        fixed = str(out / os.path.basename(target))
        with Bag(fixed) as bag:
            assert not bag.warnings()
            ours = [(c.topic, t, bytes(d)) for t, c, d in bag.messages()]
        with Reader(fixed) as reader:  # rosbags, the judge of "readable"
            theirs = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
        assert ours == theirs == kept, (target, cut)


def kept_stamps(data: bytes, cut: int) -> set[int]:
    """The times of the messages in the chunks that end before byte `cut` (from their index records)."""
    stamps = set()
    chunk_end = len(data)
    for rec in records(data, len(MAGIC), len(data)):
        if rec.op == 5:
            chunk_end = rec.end
        elif rec.op == 4 and chunk_end <= cut:
            for pos in range(rec.datapos, rec.end, 12):
                stamps.add(U32.unpack_from(data, pos)[0] * 10**9 + U32.unpack_from(data, pos + 4)[0])
    return stamps


# -- a test per mutant kind: the words of each failure, on bags rosbags wrote

@pytest.fixture(scope="module")
def plain_bags(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("plain")
    out = {}
    for kind in ("none", "bz2", "lz4"):
        path = str(folder / ("%s.bag" % kind))
        rosbags_bag(path, kind)
        with open(path, "rb") as f:
            out[kind] = f.read()
    return out


class Runs(NamedTuple):
    path: str
    info: dict
    play: dict


def run_both(data: bytes, tmp_path, env: dict[str, str], name: str = "broken.bag") -> Runs:
    path = str(tmp_path / name)
    with open(path, "wb") as f:
        f.write(data)
    info, play = run_bag([["info", path], PLAY + [path]], env, tmp_path)
    for result in (info, play):
        assert not problems_of(result, path), problems_of(result, path)
    return Runs(path, info, play)


def last_line(result: dict) -> str:
    return result["err"].strip().splitlines()[-1]


def assert_fails(runs: Runs, words: str) -> None:
    """Both commands fail, their last line naming the bag and saying `words`."""
    for result in (runs.info, runs.play):
        assert result["code"] == 1, result
        assert last_line(result).startswith("ERROR %s: %s" % (runs.path, words)), (last_line(result), words)


def assert_left_out(runs: Runs, words: str, chunk: int, messages: int) -> None:
    """Both commands go on, warning that chunk `chunk` is left out and why (info does not decompress: `play_only`
    words are said by play alone)."""
    line = "[ WARN] %s: chunk %d of " % (runs.path, chunk)
    for result in (runs.info, runs.play):
        assert result["code"] == 0, result
        warnings = [w for w in result["err"].splitlines() if w.startswith(line)]
        assert len(warnings) == 1 and words in warnings[0], (result["err"], words)
        assert warnings[0].endswith("its %d messages are left out" % messages)
    assert runs.play["out"].strip().endswith("Done.")


def chunks_of(data: bytes) -> list[tuple[bagmutants.Rec, list[bagmutants.Rec]]]:
    """Each chunk record with the index records after it."""
    out = []
    for rec in records(data, len(MAGIC), len(data)):
        if rec.op == 5:
            out.append((rec, []))
        elif rec.op == 4 and out and not any(r.op != 4 for r in out[-1][1]):
            out[-1][1].append(rec)
    return out


def messages_in(index_records: list) -> int:
    return sum(U32.unpack_from(r.fields["count"][1])[0] for r in index_records)


def header_fields(data: bytes) -> dict:
    return {k: int.from_bytes(v, "little") for k, (_, v) in records(data, len(MAGIC), len(MAGIC) + 4200)[0]
            .fields.items() if k != "op"}


def test_truncated_words(plain_bags, master, tmp_path):
    data = plain_bags["none"]
    cut = len(data) * 2 // 3
    runs = run_both(data[:cut], tmp_path, master)
    assert_fails(runs, "truncated at byte %d: the bag header puts the index at byte %d ('launcher bag reindex %s' "
                 "can still read " % (cut, header_fields(data)["index_pos"], runs.path))


def test_flipped_words_a_damaged_chunk_is_left_out_and_the_rest_played(plain_bags, master, tmp_path):
    data = bytearray(plain_bags["bz2"])
    chunk, index = chunks_of(bytes(data))[1]
    data[chunk.datapos + chunk.dlen // 2] ^= 0x10
    runs = run_both(bytes(data), tmp_path, master)
    # info reads no chunk's data: it has nothing to say; play does
    assert runs.info["code"] == 0 and not runs.info["err"]
    assert runs.play["code"] == 0 and runs.play["out"].strip().endswith("Done.")
    assert last_line(runs.play) == ("[ WARN] %s: chunk 2 of %d at byte %d: its bz2 data is damaged (Invalid data "
                                    "stream): its %d messages are left out"
                                    % (runs.path, len(chunks_of(plain_bags["bz2"])), chunk.pos, messages_in(index)))
    with Reader(str(tmp_path / "whole.bag") if _write(tmp_path / "whole.bag", plain_bags["bz2"]) else "") as reader:
        whole = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
    lost = {U32.unpack_from(plain_bags["bz2"], p)[0] * 10**9 + U32.unpack_from(plain_bags["bz2"], p + 4)[0]
            for r in index for p in range(r.datapos, r.end, 12)}
    with Bag(runs.path) as bag:
        played = [(c.topic, t, bytes(d)) for t, c, d in bag.messages()]
    assert played == [m for m in whole if m[1] not in lost] and len(lost) == messages_in(index) > 0


def _write(path, data: bytes) -> bool:
    with open(str(path), "wb") as f:
        f.write(data)
    return True


@pytest.mark.parametrize("value", [0, 12, 0x7FFFFFFF, 0xFFFFFFFF])
def test_field4_words_index_record_length(plain_bags, master, tmp_path, value):
    data = bytearray(plain_bags["lz4"])
    chunk, index = chunks_of(bytes(data))[2]
    bagmutants.put32(data, index[0].pos, value)
    runs = run_both(bytes(data), tmp_path, master)
    assert_left_out(runs, "index record 1 of %d at byte %d: an index record of %d bytes where 47 were expected"
                    % (len(index), index[0].pos, value), 3, messages_in(index))


@pytest.mark.parametrize("value", [0, 0x7FFFFFFF, 0xFFFFFFFF])
def test_field4_words_chunk_data_length(plain_bags, master, tmp_path, value):
    data = bytearray(plain_bags["none"])
    chunks = chunks_of(bytes(data))
    chunk, index = chunks[3]
    bagmutants.put32(data, chunk.datapos - 4, value)
    runs = run_both(bytes(data), tmp_path, master)
    words = ("uncompressed, but 0 bytes where its header says %d" % chunk.dlen if value == 0 else
             "its record at byte %d runs to byte %d, past the next chunk at byte %d"
             % (chunk.pos, chunk.datapos + value, chunks[4][0].pos))
    assert_left_out(runs, words, 4, messages_in(index))


def test_field4_words_chunk_info_count(plain_bags, master, tmp_path):
    """A chunk info that makes no sense loses its chunk only (how many messages: not known)."""
    data = bytearray(plain_bags["bz2"])
    info = [r for r in records(bytes(data), len(MAGIC), len(data)) if r.op == 6][1]
    bagmutants.put32(data, info.fields["count"][0], 0xFFFFFFFF)
    runs = run_both(bytes(data), tmp_path, master)
    line = ("[ WARN] %s: chunk info 2 of %d (byte %d): %d bytes of counts for 4294967295 connections (34359738360 "
            "expected): its messages are left out" % (runs.path, len(chunks_of(bytes(data))), info.pos, info.dlen))
    for result in (runs.info, runs.play):
        assert result["code"] == 0 and line in result["err"].splitlines(), result["err"]
    with Bag(runs.path) as bag:  # the rest is played
        assert sum(1 for _ in bag.messages()) == COUNT - messages_in(chunks_of(bytes(data))[1][1])


def _bag_header(data: bytes, name: str, value: int) -> bytes:
    out = bytearray(data)
    pos, old = records(data, len(MAGIC), len(MAGIC) + 4200)[0].fields[name]
    out[pos:pos + len(old)] = value.to_bytes(len(old), "little")
    return bytes(out)


def test_bag_header_words(plain_bags, master, tmp_path):
    data = plain_bags["none"]
    head = header_fields(data)
    recs = records(data, len(MAGIC), len(data))
    chunks = len(chunks_of(data))
    first_info = next(r for r in recs if r.op == 6)
    last_info = [r for r in recs if r.op == 6][-1]
    cases = [
        ("index_pos", len(data) + 1000, "truncated at byte %d: the bag header puts the index at byte %d"
         % (len(data), len(data) + 1000)),
        ("index_pos", 0, "not indexed (a recording that did not end: the bag header has no index_pos)"),
        ("index_pos", 100, "the bag header's index_pos 100 points inside the bag header"),
        ("index_pos", recs[1].pos, "the bag header's index_pos %d points at a chunk (op 5), not at the index"
         % recs[1].pos),
        ("conn_count", 0, "the bag header says 0 connections and %d chunks, but its index holds a connection record "
         "(op 7) at byte %d where chunk info 1 of %d in the index was expected" % (chunks, head["index_pos"], chunks)),
        ("conn_count", 0xFFFFFFFF, "the bag header says 4294967295 connections and %d chunks, but its index holds a "
         "chunk info (op 6) at byte %d where connection record 4 of 4294967295" % (chunks, first_info.pos)),
        ("chunk_count", chunks + 1, "the bag header says 3 connections and %d chunks, but its index (bytes %d to %d) "
         "holds 3 connection records and %d chunk infos" % (chunks + 1, head["index_pos"], len(data), chunks)),
        ("chunk_count", chunks - 1, "the bag header says 3 connections and %d chunks, but its index holds more: a "
         "chunk info at byte %d" % (chunks - 1, last_info.pos)),
    ]
    for n, (name, value, words) in enumerate(cases):
        runs = run_both(_bag_header(data, name, value), tmp_path, master, "header%d.bag" % n)
        assert_fails(runs, words)


@pytest.mark.parametrize("kind,new,words", [("bz2", "zst", "unknown compression 'zst'"),
                                            ("none", "gzip", "unknown compression 'gzip'"),
                                            ("lz4", "bz2", "its bz2 data is damaged (Invalid data stream)")])
def test_compression_words(plain_bags, master, tmp_path, kind, new, words):
    data = bytearray(plain_bags[kind])
    chunk, index = chunks_of(bytes(data))[0]
    pos, old = chunk.fields["compression"]
    data[pos:pos + len(old)] = new.encode()
    runs = run_both(bytes(data), tmp_path, master)
    if words.startswith("unknown"):  # seen in the chunk's header: info says it too
        assert_left_out(runs, words, 1, messages_in(index))
    else:
        assert runs.info["code"] == 0 and not runs.info["err"] and runs.play["code"] == 0
        assert last_line(runs.play).startswith("[ WARN] %s: chunk 1 of " % runs.path) and words in last_line(runs.play)


def test_header_length_words(plain_bags, master, tmp_path):
    data = plain_bags["bz2"]
    recs = records(data, len(MAGIC), len(data))
    chunk, index = chunks_of(data)[1]
    conn = next(r for r in recs if r.op == 7)
    broken = bytearray(data)
    bagmutants.put32(broken, chunk.pos, 0x7FFFFFFF)
    assert_left_out(run_both(bytes(broken), tmp_path, master, "chunk.bag"),
                    "its record at byte %d: a header of 2147483647 bytes (a record header has at most 65536)"
                    % chunk.pos, 2, messages_in(index))
    for name, rec, words in [("bag header", recs[0], "the bag header at byte 13"),
                             ("connection", conn, "connection record 1 of 3 in the index at byte %d" % conn.pos)]:
        broken = bytearray(data)
        bagmutants.put32(broken, rec.pos, 0xFFFFFFFF)
        runs = run_both(bytes(broken), tmp_path, master, name.replace(" ", "") + ".bag")
        assert_fails(runs, "%s: a header of 4294967295 bytes (a record header has at most 65536)" % words)
        # reindex steps over a damaged bag header to the first chunk; a damaged index it does not need
        out = tmp_path / name.replace(" ", "")
        out.mkdir()
        target, written, _, skipped = reindex.reindex(runs.path, str(out))
        assert written == COUNT and not skipped
