"""The package crawl's persistent cache: what a ROS path entry held, reused while its directories are unchanged.

roslaunch crawls every ROS_PACKAGE_PATH entry on every start; in a workspace of
hundreds of packages that is most of the time a launch takes (ros/ros_comm#535).
Like rospack's cache, this one lives under ROS_HOME, keyed by the entry's
absolute path. It records the modification time of every directory the crawl
walked and of every manifest it read, and is trusted in two steps:

- the whole crawl, while the walked directories that hold no package keep their
  times: adding, removing or moving a package changes the directory that holds it;
- each package, when it is first looked up, while its own directory and manifest
  keep theirs: a CATKIN_IGNORE, a removed manifest or a rename in place shows there.

A name the cache does not have, or a package that fails its check, sends the
index back to the disk for a fresh crawl (as rospack re-crawls on a miss). So a
launch stats the few dozen folders of a big workspace and the packages it uses,
not every package. The one change this does not see is an unused package
renamed in place to the name of a package that comes later in the walk: two
packages of one name, where rospkg's own answer depends on directory order.
The file is marshalled tuples (a quarter of the time of JSON's import and decoding).

File systems keep modification times at the kernel's clock tick (milliseconds), so
a change made in the same tick as the crawl could keep the time the cache holds.
As git does for its index ("racy git"), a crawl that saw anything modified within
RACY_NS before it is not reused: it is made again until the tree has settled.
"""

from __future__ import annotations

import os
import time

from launcher.workspace.roshome import read_cache, write_cache

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any

VERSION = 3
RACY_NS = 2_000_000_000
FILE = os.path.join("launcher", "package_crawl_cache.marshal")
MANIFEST_NAMES = ("package.xml", "manifest.xml")  # (packages.PACKAGE_FILE, packages.MANIFEST_FILE)


class Crawl:
    """One path entry's crawl: its packages (name, dir) in walk order, its warnings, and what to check."""

    __slots__ = ("packages", "warnings", "dirs", "manifests", "crawled_at", "_times")

    def __init__(self) -> None:
        self.crawled_at = time.time_ns()
        self.packages: list[tuple[str, str]] = []
        self.warnings: list[str] = []
        self.dirs: list[tuple[str, int]] = []  # (directory, st_mtime_ns)
        self.manifests: list[tuple[str, int, int]] = []  # (file, st_mtime_ns, st_size)
        self._times: dict[str, Any] | None = None  # path -> what dirs/manifests hold, for package_unchanged

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

    def settled(self) -> bool:
        """Nothing it recorded was modified so close to the crawl that a later change could keep the time."""
        settled = self.crawled_at - RACY_NS
        return not (any(m >= settled for _, m in self.dirs) or any(m >= settled for _, m, _ in self.manifests))

    def tree_unchanged(self) -> bool:
        """The walked directories that hold no package have their times: no package came, went or moved."""
        package_dirs = {d for _, d in self.packages}
        for d, mtime in self.dirs:
            if d not in package_dirs and _mtime(d) != mtime:
                return False
        return True

    def package_unchanged(self, package_dir: str) -> bool:
        """The package's directory and manifest have their times: not ignored, removed or renamed in place."""
        if self._times is None:
            self._times = dict(self.dirs)
            self._times.update((f, (m, size)) for f, m, size in self.manifests)
        times = self._times
        if package_dir in times and _mtime(package_dir) != times[package_dir]:
            return False
        for name in MANIFEST_NAMES:
            f = os.path.join(package_dir, name)
            if f in times:
                try:
                    st = os.stat(f)
                except OSError:
                    return False
                if (st.st_mtime_ns, st.st_size) != times[f]:
                    return False
        return True

    def unchanged(self) -> bool:
        """All of it: the tree and every package."""
        return self.tree_unchanged() and all(self.package_unchanged(d) for _, d in self.packages)

    def to_record(self) -> tuple[Any, ...]:
        return (tuple(self.packages), tuple(self.warnings), tuple(self.dirs), tuple(self.manifests), self.crawled_at)

    @classmethod
    def from_record(cls, record: tuple[Any, ...]) -> Crawl:
        crawl = cls()
        packages, warnings, dirs, manifests, crawl.crawled_at = record
        crawl.packages, crawl.warnings, crawl.dirs, crawl.manifests = (
            list(packages), list(warnings), list(dirs), list(manifests))
        return crawl


class CrawlCache:
    """The cache file of one ROS_HOME: read at the first lookup, written after a fresh crawl."""

    def __init__(self, ros_home: str | None):
        self.path = os.path.join(ros_home, FILE) if ros_home else None
        self._entries: dict[str, Any] | None = None

    def __getstate__(self) -> dict[str, object]:
        """Pickled (a plan made in a process of its own, run/apart.py): the path only; the entries are read again
        if ever looked up."""
        return {"path": self.path, "_entries": None}

    def _load(self) -> dict[str, Any]:
        if self._entries is None:
            self._entries = read_cache(self.path, VERSION)  # (none, or unreadable: crawl)
        return self._entries

    def lookup(self, root: str) -> Crawl | None:
        """The cached crawl of `root`, if its tree is unchanged (each package is checked when used)."""
        record = self._load().get(root)
        if record is None:
            return None
        try:
            crawl = Crawl.from_record(record)
        except (TypeError, ValueError):  # not the five fields this version writes
            return None
        return crawl if crawl.settled() and crawl.tree_unchanged() else None

    def store(self, root: str, crawl: Crawl) -> None:
        """Remember a fresh crawl (best effort: a read-only ROS_HOME only costs the next launch a crawl)."""
        entries = self._load()
        entries[root] = crawl.to_record()
        write_cache(self.path, VERSION, entries)


def _mtime(path: str) -> int:
    try:
        return os.stat(path).st_mtime_ns
    except OSError:
        return -1
