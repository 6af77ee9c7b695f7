"""The package crawl's persistent cache: what a ROS path entry held, reused while its directories are unchanged.

roslaunch crawls every ROS_PACKAGE_PATH entry on every start; in a workspace of
hundreds of packages that is most of the time a launch takes (ros/ros_comm#535).
Like rospack's cache, this one lives under ROS_HOME. It is keyed by the
entry's absolute path, and it stays valid while every directory the crawl walked
and every manifest it read have the modification time (and manifest size) they
had: adding, removing or moving a package, or a CATKIN_IGNORE, changes the
mtime of the directory that holds it; renaming a package changes its manifest.
Checking that is a stat per walked directory, instead of a scandir per directory
and a parse per manifest.

File systems keep modification times at the kernel's clock tick (milliseconds), so
a change made in the same tick as the crawl could keep the time the cache holds.
As git does for its index ("racy git"), a crawl that saw anything modified within
RACY_NS before it is not reused: it is made again until the tree has settled.
"""

from __future__ import annotations

import json
import os
import time
from typing import Any

VERSION = 2
RACY_NS = 2_000_000_000
FILE = os.path.join("launcher", "package_crawl_cache.json")


class Crawl:
    """One path entry's crawl: its packages (name, dir) in walk order, its warnings, and what to check."""

    __slots__ = ("packages", "warnings", "dirs", "manifests", "crawled_at")

    def __init__(self) -> None:
        self.crawled_at = time.time_ns()
        self.packages: list[tuple[str, str]] = []
        self.warnings: list[str] = []
        self.dirs: list[tuple[str, int]] = []  # (directory, st_mtime_ns)
        self.manifests: list[tuple[str, int, int]] = []  # (file, st_mtime_ns, st_size)

    def walked(self, d: str) -> None:
        try:
            self.dirs.append((d, os.stat(d).st_mtime_ns))
        except OSError:
            self.dirs.append((d, -1))

    def read(self, manifest: str) -> None:
        try:
            st = os.stat(manifest)
            self.manifests.append((manifest, st.st_mtime_ns, st.st_size))
        except OSError:
            self.manifests.append((manifest, -1, -1))

    def still_valid(self) -> bool:
        settled = self.crawled_at - RACY_NS
        if any(m >= settled for _, m in self.dirs) or any(m >= settled for _, m, _ in self.manifests):
            return False  # changed too close to the crawl to tell a later change by its time
        for d, mtime in self.dirs:
            try:
                if os.stat(d).st_mtime_ns != mtime:
                    return False
            except OSError:
                return False
        for f, mtime, size in self.manifests:
            try:
                st = os.stat(f)
            except OSError:
                return False
            if st.st_mtime_ns != mtime or st.st_size != size:
                return False
        return True

    def to_json(self) -> dict[str, Any]:
        return {"packages": self.packages, "warnings": self.warnings, "dirs": self.dirs, "manifests": self.manifests,
                "crawled_at": self.crawled_at}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Crawl:
        crawl = cls()
        crawl.packages = [(str(n), str(d)) for n, d in data["packages"]]
        crawl.warnings = [str(w) for w in data["warnings"]]
        crawl.dirs = [(str(d), int(m)) for d, m in data["dirs"]]
        crawl.manifests = [(str(f), int(m), int(s)) for f, m, s in data["manifests"]]
        crawl.crawled_at = int(data["crawled_at"])
        return crawl


class CrawlCache:
    """The cache file of one ROS_HOME: read at the first lookup, written after a fresh crawl."""

    def __init__(self, ros_home: str | None):
        self.path = os.path.join(ros_home, FILE) if ros_home else None
        self._entries: dict[str, Any] | None = None

    def _load(self) -> dict[str, Any]:
        if self._entries is None:
            self._entries = {}
            if self.path:
                try:
                    with open(self.path, encoding="utf-8") as f:
                        data = json.load(f)
                    if data.get("version") == VERSION and isinstance(data.get("entries"), dict):
                        self._entries = data["entries"]
                except (OSError, ValueError, AttributeError):
                    pass  # no cache yet, or one we cannot read: crawl
        return self._entries

    def lookup(self, root: str) -> Crawl | None:
        """The cached crawl of `root`, if nothing it depends on has changed."""
        data = self._load().get(root)
        if data is None:
            return None
        try:
            crawl = Crawl.from_json(data)
        except (KeyError, TypeError, ValueError):
            return None
        return crawl if crawl.still_valid() else None

    def store(self, root: str, crawl: Crawl) -> None:
        """Remember a fresh crawl (best effort: a read-only ROS_HOME only costs the next launch a crawl)."""
        entries = self._load()
        entries[root] = crawl.to_json()
        if not self.path:
            return
        tmp = "%s.%d.tmp" % (self.path, os.getpid())
        try:
            os.makedirs(os.path.dirname(self.path), exist_ok=True)
            with open(tmp, "w", encoding="utf-8") as f:
                json.dump({"version": VERSION, "entries": entries}, f, separators=(",", ":"))
            os.replace(tmp, self.path)  # atomic: a launch reading at the same time sees old or new
        except OSError:
            try:
                os.unlink(tmp)
            except OSError:
                pass
