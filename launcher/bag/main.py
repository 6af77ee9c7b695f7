"""`launcher bag record|play|info|reindex`: rosbag's command lines, parsed and dispatched to their modules."""

from __future__ import annotations

import argparse
import asyncio
import re
import sys

from launcher.bag import rosargs

COMMANDS = ("record", "play", "info", "reindex")
USAGE = "usage: launcher bag {record,play,info,reindex} [options]"


def _duration(text: str) -> float:
    """rosbag's --duration: seconds, or a number with s, m or h."""
    match = re.fullmatch(r"(\d+(?:\.\d*)?)([smh]?)", text.strip())
    if not match:
        raise argparse.ArgumentTypeError("duration must be a number of seconds, or end in s, m or h: %r" % text)
    return float(match.group(1)) * {"": 1, "s": 1, "m": 60, "h": 3600}[match.group(2)]


def _regex(text: str) -> str:
    try:
        re.compile(text)
    except re.error as exc:
        raise argparse.ArgumentTypeError("%r is not a regular expression: %s" % (text, exc)) from None
    return text


def record_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="launcher bag record", description="Record topics into a bag (rosbag record).")
    p.add_argument("topics", nargs="*", metavar="TOPIC")
    p.add_argument("-a", "--all", action="store_true", help="record all topics")
    p.add_argument("-e", "--regex", action="store_true", help="match topics using regular expressions")
    p.add_argument("-x", "--exclude", type=_regex, metavar="EXCLUDE_REGEX", help="exclude topics matching this regex")
    p.add_argument("-q", "--quiet", action="store_true", help="suppress console output")
    p.add_argument("-o", "--output-prefix", metavar="PREFIX", help="prepend PREFIX to the beginning of the bag name")
    p.add_argument("-O", "--output-name", metavar="NAME", help="record to bag with name NAME.bag")
    p.add_argument("--split", action="store_true", help="split the bag when maximum size or duration is reached")
    p.add_argument("--max-splits", type=int, default=0, metavar="MAX_SPLITS", help="keep at most this many bags")
    p.add_argument("--size", type=int, default=0, metavar="SIZE", help="record a bag of maximum size SIZE MB")
    p.add_argument("--duration", type=_duration, default=0.0, help="record a bag of maximum duration (s, m or h)")
    p.add_argument("-b", "--buffsize", type=int, default=256, metavar="SIZE",
                   help="the buffer of messages waiting for the disk, in MB (default 256; 0: unbounded); when it "
                        "is full, the oldest are dropped with a warning")
    p.add_argument("--chunksize", type=int, default=768, metavar="SIZE", help="chunk size in KB")
    p.add_argument("-l", "--limit", type=int, default=0, metavar="NUM", help="only record NUM messages on each topic")
    p.add_argument("--node", help="record all topics subscribed to by a specific node")
    p.add_argument("-j", "--bz2", action="store_true", help="use BZ2 compression")
    p.add_argument("--lz4", action="store_true", help="use LZ4 compression")
    p.add_argument("--tcpnodelay", action="store_true", help="use the TCP_NODELAY transport hint (always on here)")
    return p


def record_main(argv: list[str]) -> int:
    from launcher.bag import record  # rosbags: only for the command that runs

    ros = rosargs.split(argv, "record")
    p = record_parser()
    o = p.parse_args(ros.args)
    if o.bz2 and o.lz4:
        p.error("-j/--bz2 and --lz4 cannot both be given")
    if o.output_name and o.output_prefix:
        p.error("-o and -O cannot both be given")
    if o.regex:
        for topic in o.topics:
            _regex_or_exit(p, topic)
    if not (o.all or o.topics or o.node):
        p.error("you must specify a topic name, -a or --node")
    if o.buffsize < 0 or o.chunksize <= 0:
        p.error("-b/--buffsize must be 0 (unbounded) or more, and --chunksize more than 0")
    if o.split and not (o.size or o.duration):
        p.error("Split specified without giving a maximum duration or size")  # (rosbag's words)
    if o.max_splits and not o.split:
        p.error("--max-splits needs --split")
    opts = record.RecordOptions(
        topics=[] if o.regex else record.resolve_topics(o.topics, ros.name), all=o.all,
        regex=o.topics if o.regex else [], exclude=o.exclude, output_name=o.output_name,
        output_prefix=o.output_prefix, split=o.split, size=o.size * 1048576, duration=o.duration,
        max_splits=o.max_splits, compression="bz2" if o.bz2 else "lz4" if o.lz4 else "none", limit=o.limit,
        node=o.node and record.resolve_topics([o.node], ros.name)[0], buffer_size=o.buffsize << 20,
        chunk_size=o.chunksize * 1024, quiet=o.quiet)
    return asyncio.run(record.record(opts, ros.name, ros.master_uri, ros.host))


def _regex_or_exit(p: argparse.ArgumentParser, text: str) -> None:
    try:
        _regex(text)
    except argparse.ArgumentTypeError as exc:
        p.error(str(exc))


def info_main(argv: list[str]) -> int:
    from launcher.bag import info

    p = argparse.ArgumentParser(prog="launcher bag info", description="Summarize the contents of bags (rosbag info).")
    p.add_argument("bags", nargs="+", metavar="BAG")
    p.add_argument("-y", "--yaml", action="store_true", help="print information in YAML format")
    p.add_argument("-k", "--key", help="print information on the given key (-y's names: duration, topics[0].type)")
    p.add_argument("--freq", action="store_true", help="display topic message frequency statistics")
    o = p.parse_args(argv)
    if o.key and not o.yaml:
        p.error("you can only specify key when printing in YAML format")
    return info.main(o.bags, o.yaml, o.key, o.freq)


def reindex_main(argv: list[str]) -> int:
    from launcher.bag import reindex

    p = argparse.ArgumentParser(prog="launcher bag reindex",
                                description="Rebuild the index of an .active or truncated bag (rosbag reindex).")
    p.add_argument("bags", nargs="+", metavar="BAG")
    p.add_argument("--output-dir", metavar="DIR", help="write the reindexed bags here (default: next to each bag)")
    o = p.parse_args(argv)
    return reindex.main(o.bags, o.output_dir)


def play_main(argv: list[str]) -> int:
    from launcher.bag import play

    return play.main(argv)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if args else 2
    handler = {"record": record_main, "play": play_main, "info": info_main, "reindex": reindex_main}.get(args[0])
    if handler is None:
        print("launcher bag: unknown command '%s'\n%s" % (args[0], USAGE), file=sys.stderr)
        return 2
    try:
        return handler(args[1:])
    except KeyboardInterrupt:
        return 130
