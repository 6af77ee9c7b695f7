"""Parsed rosparam YAML kept under ROS_HOME between runs: a document's exact text → its value.

Most launches load the parameter files the launch before them loaded. Parsing
them needs PyYAML, whose import alone (it compiles its scanner's and resolver's
regexes) costs more than the rest of a `--dump-params` of a small robot. So a
document whose value is a plain tree (str, int, float, bool, None, lists and
maps, no aliases: what `rosyaml` builds directly from libyaml's nodes) is kept
here, marshalled, keyed by its text and the loader's flavour (rosparam's angle
tags or plain YAML). An unchanged file is then read, compared and unmarshalled,
never parsed, and PyYAML is not imported. The key is the text itself, not a file
time, so an entry cannot go stale. Anything else (binary, timestamps, aliases,
errors) is parsed every time.

The file is written and read as the crawl cache's is (`roshome.write_cache`).
"""

from __future__ import annotations

import marshal
import os

from launcher.workspace.roshome import read_cache, write_cache

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any

# (2: documents nested more than rosyaml.MAX_DEPTH deep are no longer kept; 3: a '?' in a flow collection is read as
# PyYAML reads it, and libyaml's reading of one, kept by 2, is no value of ROS's)
VERSION = 3
FILE = os.path.join("launcher", "yaml_cache.marshal")
MAX_CHARS = 2 * 1024 * 1024  # texts kept in all: the file stays small enough to read in about a millisecond


class YamlCache:
    """The YAML cache of one ROS_HOME: read at the first document, written once by `save` if it learned any."""

    def __init__(self, ros_home: str | None):
        self.path = os.path.join(ros_home, FILE) if ros_home else None
        self._entries: dict[tuple[str, bool], bytes] | None = None
        self._used: dict[tuple[str, bool], bytes] = {}  # this run's documents, in order: kept first on save
        self._learned = False

    def load(self, text: str, *, filename: str | None = None, first_line: int = 1, angles: bool = True) -> Any:
        """`rosyaml.load_yaml`'s value for `text` (a fresh object each call); raises RosYamlError as it does."""
        key = (text, angles)
        blob = self._used.get(key)
        if blob is None:
            blob = self._read().get(key)
        if blob is not None:
            self._used[key] = blob
            return marshal.loads(blob)
        from launcher.params.rosyaml import parse_yaml  # PyYAML: imported only for a text not seen before

        value, plain = parse_yaml(text, filename=filename, first_line=first_line, angles=angles)
        if plain and len(text) <= MAX_CHARS:
            self._used[key] = marshal.dumps(value)
            self._learned = True
        return value

    def save(self) -> None:
        """Write this run's documents, then older ones while they fit (best effort, atomic)."""
        if not self._learned or not self.path:
            return
        kept, chars = {}, 0
        for key, blob in list(self._used.items()) + list(self._read().items()):
            if key in kept or chars + len(key[0]) > MAX_CHARS:
                continue
            kept[key] = blob
            chars += len(key[0])
        write_cache(self.path, VERSION, kept)
        self._learned = False

    def _read(self) -> dict[tuple[str, bool], bytes]:
        if self._entries is None:
            self._entries = read_cache(self.path, VERSION)  # (none yet, or another version's: parse)
        return self._entries
