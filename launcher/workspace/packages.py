"""Finding ROS packages, node executables and `$(find)` paths, as roslaunch does on Debian.

The rules are those of rospkg (package crawl), catkin's `find_in_workspaces`
(install/devel spaces from `CMAKE_PREFIX_PATH`) and roslib's `find_node` /
`find_resource`, including their quirks, because users' launch files were
written against them. Unlike those libraries, a `PackageIndex` walks each
directory at most once per run and answers later questions from memory: a
launch with 1000 nodes must not walk a package 1000 times.
"""

from __future__ import annotations

import os
import pyexpat
import stat
from collections.abc import Callable, Iterator, Mapping

from launcher.workspace.crawlcache import Crawl, CrawlCache
from launcher.model.errors import LaunchError
from launcher.workspace.roshome import ros_home
from launcher.model.suggest import did_you_mean

PACKAGE_FILE = "package.xml"
MANIFEST_FILE = "manifest.xml"  # rosbuild packages: the directory name is the package name
CATKIN_MARKER = ".catkin"
# Debian's rospkg always appends /usr/share to ROS_PACKAGE_PATH, and only looks one level deep there.
SYSTEM_SHARE = "/usr/share"
# catkin always searches /usr after the workspaces of CMAKE_PREFIX_PATH.
SYSTEM_PREFIX = "/usr"
_CATKIN_IGNORE_MARKERS = frozenset(("AMENT_IGNORE", "CATKIN_IGNORE", "COLCON_IGNORE"))
_USER_RX = stat.S_IRUSR | stat.S_IXUSR


# Nodes built in (launcher/bag), run where their package is not found: on a ROS machine the installed
# rosbag runs, as with roslaunch. `BAG_MAIN` stands for them; command.node_command runs it with our python.
BUILTIN_NODES = frozenset({("rosbag", "record"), ("rosbag", "play")})
BAG_MAIN = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bag", "__main__.py")


class PackageNotFound(LaunchError):
    """A package name that is on neither ROS_PACKAGE_PATH nor /usr/share."""

    def __init__(self, package: str, ros_paths: list[str] | tuple[str, ...] = (), hint: str = ""):
        self.package = package
        self.ros_paths = tuple(ros_paths)
        self.hint = hint  # "did you mean ...?" among the packages there are, or ""
        # rospkg's ResourceNotFound wording, which roslaunch shows as is (and a hint on its first line)
        text = "Resource not found: %s" % package + (" (%s)" % hint if hint else "")
        for i, p in enumerate(self.ros_paths):
            text += "\nROS path [%d]=%s" % (i, p)
        super().__init__(text)


class ExecutableNotFound(LaunchError):
    """A `<node type=...>` with no executable file of that name in its package."""

    def __init__(self, package: str, node_type: str, not_executable: str | None = None, hint: str = ""):
        self.package = package
        self.node_type = node_type
        self.not_executable = not_executable
        self.hint = hint
        text = ("Cannot locate node of type [%s] in package [%s]. Make sure file exists in package path "
                "and permission is set to executable (chmod +x)" % (node_type, package))
        if not_executable:
            import shlex  # (for this message only: a run that finds its nodes does not import it)
            # roslaunch stops at the sentence above; the usual cause is a script committed without its
            # exec bit, and the file is right there
            text += "\nThe file [%s] exists but is not executable: run chmod +x %s" % (
                not_executable, shlex.quote(not_executable))
        elif hint:  # (a typo in type=: "did you mean ...?" among the package's executables)
            text += "\nThere is no executable [%s] in package [%s]: %s" % (node_type, package, hint)
        super().__init__(text)


class MultipleResources(LaunchError):
    """`launch pkg file.launch` where the package holds several files of that name."""

    def __init__(self, package: str, filename: str, matches: list[str]):
        self.package = package
        self.filename = filename
        self.matches = tuple(matches)
        super().__init__("multiple files named [%s] in package [%s]:%s\nPlease specify full path instead"
                         % (filename, package, "".join("\n- %s" % m for m in matches)))


def ros_paths(environ: Mapping[str, str]) -> list[str]:
    """The package search path in precedence order: ROS_ROOT, ROS_PACKAGE_PATH, /usr/share."""
    paths = []
    root = environ.get("ROS_ROOT")
    if root:
        paths.append(os.path.normpath(root))
    rpp = environ.get("ROS_PACKAGE_PATH", "") + os.pathsep + SYSTEM_SHARE
    paths.extend(p for p in rpp.split(os.pathsep) if p.strip())
    return paths


def catkin_workspaces(environ: Mapping[str, str]) -> list[str]:
    """CMAKE_PREFIX_PATH entries that hold a `.catkin` marker file, then /usr (catkin's rule)."""
    entries = [p for p in environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep) if p]
    spaces = [p for p in entries if os.path.isfile(os.path.join(p, CATKIN_MARKER))]
    spaces.append(SYSTEM_PREFIX)
    return spaces


def _walk(top: str) -> Iterator[tuple[str, list[str], list[str]]]:
    """`os.walk(top, followlinks=True)` (same order, callers may prune `dirs`), except that a
    symlink to a directory already entered through a symlink is not entered again, so link
    cycles cannot run away. (A loop needs a symlink; remembering the targets of followed
    symlinks by device and inode costs no extra system call: is_dir() has stat'ed them.)"""
    followed: set[tuple[int, int]] = set()
    stack = [top]
    while stack:
        path = stack.pop()
        dirs: list[str] = []
        files: list[str] = []
        targets: dict[str, tuple[int, int]] = {}
        try:
            with os.scandir(path) as it:
                for entry in it:
                    try:
                        is_dir = entry.is_dir()
                        if is_dir and entry.is_symlink():
                            st = entry.stat()
                            targets[entry.name] = (st.st_dev, st.st_ino)
                    except OSError:
                        is_dir = False
                    if is_dir:
                        dirs.append(entry.name)
                    else:
                        files.append(entry.name)
        except OSError:
            continue  # unreadable directory: os.walk skips it silently too
        yield path, dirs, files
        children = []
        for name in dirs:
            target = targets.get(name)
            if target is not None:
                if target in followed:
                    continue
                followed.add(target)
            children.append(os.path.join(path, name))
        stack.extend(reversed(children))


def _package_name(manifest: str) -> tuple[str | None, bool]:
    """(the `<name>` of a package.xml, whether it is a metapackage); (None, False) if unreadable."""
    try:
        with open(manifest, "rb") as f:
            data = f.read()
    except OSError:
        return None, False
    return read_package_xml(data)


def read_package_xml(data: bytes) -> tuple[str | None, bool]:
    """(the text of the first `<name>` under the root, whether `<export>` holds a `<metapackage>`).

    Read with expat as minidom reads it (rospkg's parser), namespaces included, so that the same
    manifests are accepted; only the text of `<name>` itself counts, not that of elements inside it.
    (None, False) for a document that is not well-formed XML or has no `<name>`.
    """
    path: list[str] = []  # the tags from the root down to the current element
    name_text: list[str] | None = None
    in_name = False  # inside the first <name> under the root (its text, at depth 2, is the name)
    is_meta = False

    def start(tag: str, attrib: dict[str, str]) -> None:
        nonlocal name_text, in_name, is_meta
        if " " in tag:  # "uri local [prefix]": the qualified name minidom reports
            parts = tag.split(" ")
            tag = parts[2] + ":" + parts[1] if len(parts) == 3 else parts[-1]
        path.append(tag)
        if len(path) == 2 and tag == "name" and name_text is None:
            name_text = []
            in_name = True
        elif len(path) == 3 and path[1] == "export" and tag == "metapackage":
            is_meta = True

    def end(tag: str) -> None:
        nonlocal in_name
        if len(path) == 2:
            in_name = False
        path.pop()

    def chars(text: str) -> None:
        if in_name and len(path) == 2:
            name_text.append(text)  # type: ignore[union-attr]

    if not _parsed(data, start, end, chars) or name_text is None:
        return None, False
    return "".join(name_text).strip(" \n\r\t"), is_meta


def package_version(manifest: str) -> str | None:
    """The text of the first `<version>` under a package.xml's root (its own text, as `rosversion PKG` reads it);
    None if the file is unreadable, not well-formed or has none."""
    try:
        with open(manifest, "rb") as f:
            data = f.read()
    except OSError:
        return None
    depth = 0
    text: list[str] | None = None  # the first <version>'s text, once it has begun
    in_version = False

    def start(tag: str, attrib: dict[str, str]) -> None:
        nonlocal depth, text, in_version
        depth += 1
        if depth == 2 and tag == "version" and text is None:
            text, in_version = [], True

    def end(tag: str) -> None:
        nonlocal depth, in_version
        if depth == 2:
            in_version = False
        depth -= 1

    def chars(data: str) -> None:
        if in_version and depth == 2:
            text.append(data)  # type: ignore[union-attr]

    return "".join(text) if _parsed(data, start, end, chars) and text is not None else None


def _parsed(data: bytes, start: Callable[[str, dict[str, str]], None], end: Callable[[str], None],
            chars: Callable[[str], None]) -> bool:
    """`data` read by expat with these handlers, as minidom reads it (rospkg's parser: namespace processing, a
    qualified tag as "uri local [prefix]"); False if it is not well-formed XML."""
    parser = pyexpat.ParserCreate(None, " ")
    parser.buffer_text = True
    parser.namespace_prefixes = True
    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(data, True)
    except pyexpat.ExpatError:
        return False
    return True


def _crawl_path(root: str) -> Crawl:
    """The packages under one ROS path entry (rospkg's list_by_path rules), and what they depend on."""
    crawl = Crawl()
    for d, dirs, files in _walk(root):
        crawl.walked(d)
        if "CATKIN_IGNORE" in files:
            del dirs[:]
            continue
        if PACKAGE_FILE in files:
            manifest = os.path.join(d, PACKAGE_FILE)
            crawl.read(manifest)
            name, is_meta = _package_name(manifest)
            if name is None:
                crawl.warnings.append("ignoring unreadable package manifest %s" % manifest)
                del dirs[:]
                continue
            # rospkg's RosPack lists packages, not metapackages (those are "stacks").
            if not is_meta:
                crawl.packages.append((name, d))
                del dirs[:]
                continue
        if MANIFEST_FILE in files:
            crawl.packages.append((os.path.basename(d), d))
            del dirs[:]
            continue
        if PACKAGE_FILE in files or "rospack_nosubdirs" in files or d.startswith(SYSTEM_SHARE + "/"):
            del dirs[:]
            continue
        # rospkg removes hidden dirs with a list comprehension that mutates the list it
        # iterates: the entry right after each removed one survives. Same result here.
        i = 0
        while i < len(dirs):
            if dirs[i][0] == ".":
                del dirs[i]
            i += 1
    return crawl


def package_of(path: str) -> tuple[str, str]:
    """(name, directory) of the package holding `path` (rospkg.get_package_name: the nearest package.xml up)."""
    d = os.path.dirname(os.path.abspath(path))
    while True:
        manifest = os.path.join(d, "package.xml")
        if os.path.isfile(manifest):
            with open(manifest, "rb") as f:
                name, _meta = read_package_xml(f.read())
            if name:
                return name, d
        parent = os.path.dirname(d)
        if parent == d:
            raise LaunchError("[%s] is not inside a ROS package (no package.xml above it)" % path)
        d = parent


class PackageIndex:
    """Where packages and their files are, for one run. Crawls lazily, each directory once."""

    def __init__(self, environ: Mapping[str, str] | None = None, warn: Callable[[str], None] | None = None,
                 use_cache: bool = True):
        """`warn` is told each warning as the lazy crawl finds it (they also collect in `warnings`);
        `use_cache`: keep crawls in ROS_HOME's crawl cache (launcher/workspace/crawlcache.py)."""
        env = os.environ if environ is None else environ
        self.ros_paths: list[str] = ros_paths(env)
        self.workspaces: list[str] = catkin_workspaces(env)
        self.warnings: list[str] = []
        self._warn = warn
        self._cache = CrawlCache(ros_home(env) if use_cache else None)
        self._located: dict[str, str] = {}
        self._uncrawled = list(self.ros_paths)  # crawled in precedence order, on demand
        self._unchecked: dict[str, Crawl] = {}  # package -> the cached crawl it came from, until first used
        self._from_cache = False  # some path entry's packages came from the crawl cache
        self._fresh = False  # True once a miss sent us to the disk: the cache is not read again
        self._files: dict[str, dict[str, list[str]]] = {}  # dir -> file name -> paths, os.walk order
        self._nodes: dict[tuple[str, str], str] = {}
        self._catkin: dict[tuple[str, tuple[str, ...], str | None, bool], list[str]] = {}
        self._source_spaces: dict[str, list[str]] = {}
        self._source_packages: dict[str, list[tuple[str, str]]] = {}

    def __getstate__(self) -> dict[str, object]:
        """Pickled (a plan made in a process of its own, run/apart.py): without its `warn`, which told its
        warnings there; they stay in `warnings`."""
        return dict(self.__dict__, _warn=None)

    def _warning(self, text: str) -> None:
        self.warnings.append(text)
        if self._warn is not None:
            self._warn(text)

    # -- packages ---------------------------------------------------------------------------

    def _crawl(self, path: str) -> None:
        """Register the packages under one ROS path entry, from the crawl cache while its tree is unchanged."""
        root = os.path.abspath(path)
        crawl = None if self._fresh else self._cache.lookup(root)
        cached = crawl is not None
        self._from_cache |= cached
        if crawl is None:
            crawl = _crawl_path(root)
            self._cache.store(root, crawl)
        found: set[str] = set()
        for name, d in crawl.packages:
            # first path entry wins; inside one entry the first directory in walk order wins
            if name not in found:
                found.add(name)
                if name not in self._located:
                    self._located[name] = d
                    if cached:
                        self._unchecked[name] = crawl
        for text in crawl.warnings:
            if text not in self.warnings:  # (a fresh crawl after a miss finds the same ones again)
                self._warning(text)

    def _recrawl(self) -> bool:
        """After a miss or a changed package: forget what the cache said and crawl the disk (once per index)."""
        if self._fresh or not self._from_cache:
            return False
        self._fresh = True
        self._located.clear()
        self._unchecked.clear()
        self._uncrawled = list(self.ros_paths)
        return True

    def get_path(self, pkg: str) -> str:
        """The directory of package `pkg`; raises PackageNotFound."""
        while pkg not in self._located and self._uncrawled:
            self._crawl(self._uncrawled.pop(0))
        d = self._located.get(pkg)
        crawl = self._unchecked.pop(pkg, None)
        if d is None or (crawl is not None and not crawl.package_unchanged(d)):
            if self._recrawl():
                return self.get_path(pkg)
            # (every path entry is crawled by now: the hint costs no walk)
            raise PackageNotFound(pkg, self.ros_paths, did_you_mean(pkg, self._located))
        return d

    def packages(self) -> dict[str, str]:
        """Every package on the path: name -> directory."""
        while self._uncrawled:
            self._crawl(self._uncrawled.pop(0))
        if any(not crawl.package_unchanged(self._located[name]) for name, crawl in self._unchecked.items()):
            self._recrawl()
            return self.packages()
        self._unchecked.clear()
        return dict(self._located)

    # -- catkin spaces ------------------------------------------------------------------------

    def _source_space_paths(self, workspace: str) -> list[str]:
        """The source spaces a devel space's `.catkin` file lists (';'-separated, unique by realpath)."""
        if workspace not in self._source_spaces:
            result: list[str] = []
            if workspace != SYSTEM_PREFIX:
                try:
                    with open(os.path.join(workspace, CATKIN_MARKER)) as f:
                        data = f.read()
                except OSError:
                    data = ""
                reals = set()
                if data:
                    for p in data.split(";"):
                        r = os.path.realpath(p)
                        if r not in reals:
                            result.append(p)
                            reals.add(r)
            self._source_spaces[workspace] = result
        return self._source_spaces[workspace]

    def _packages_in_source(self, source: str) -> list[tuple[str, str]]:
        """(name, relative dir) of the packages in a source space (catkin_pkg's crawl rules)."""
        if source not in self._source_packages:
            result = []
            for d, dirs, files in _walk(source):
                if _CATKIN_IGNORE_MARKERS.intersection(dirs) or _CATKIN_IGNORE_MARKERS.intersection(files):
                    del dirs[:]
                    continue
                if PACKAGE_FILE in files:
                    name, _meta = _package_name(os.path.join(d, PACKAGE_FILE))
                    if name is not None:
                        result.append((name, os.path.relpath(d, source)))
                    del dirs[:]
                    continue
                if d.startswith(SYSTEM_SHARE + "/"):
                    del dirs[:]
                    continue
                dirs[:] = [x for x in dirs if not x.startswith(".")]
            self._source_packages[source] = result
        return self._source_packages[source]

    def catkin_dirs(self, pkg: str, subdirs: tuple[str, ...], path: str | None = None,
                    first_match_only: bool = False) -> list[str]:
        """catkin's find_in_workspaces(subdirs, project=pkg, path, first_matching_workspace_only=True).

        `libexec` implies `lib` before it, as in catkin.
        """
        key = (pkg, subdirs, path, first_match_only)
        if key in self._catkin:
            return self._catkin[key]
        search = list(subdirs)
        if "libexec" in search:
            search.insert(search.index("libexec"), "lib")
        found: list[str] = []
        for ws in self.workspaces:
            for cand in self._workspace_candidates(ws, pkg, search, path):
                if os.path.exists(cand):
                    found.append(cand)
                    if first_match_only:
                        break
            if found:
                break
        self._catkin[key] = found
        return found

    def _workspace_candidates(self, ws: str, pkg: str, search: list[str], path: str | None) -> Iterator[str]:
        for sub in search:
            cand = os.path.join(ws, sub, pkg)
            yield os.path.join(cand, path) if path else cand
            if sub == "share":
                # a devel space also answers with the package's source dir
                for source in self._source_space_paths(ws):
                    rels = [rel for name, rel in self._packages_in_source(source) if name == pkg]
                    if rels:
                        cand = source if rels[0] == os.curdir else os.path.join(source, rels[0])
                        yield os.path.join(cand, path) if path else cand

    # -- files inside packages ------------------------------------------------------------

    def _index(self, directory: str) -> dict[str, list[str]]:
        """File name -> the paths of the non-directory entries of that name under `directory`, in os.walk
        order with hidden dirs pruned (roslib's _find_resource walk). One walk per directory per run."""
        index = self._files.get(directory)
        if index is None:
            index = {}
            for d, dirs, files in _walk(directory):
                for f in files:
                    index.setdefault(f, []).append(os.path.join(d, f))
                dirs[:] = [x for x in dirs if not x.startswith(".")]
            self._files[directory] = index
        return index

    def _named(self, directory: str, name: str) -> list[str]:
        return self._index(directory).get(name, [])

    def file_names(self, pkg: str) -> list[str]:
        """The names of the files where `launch PKG FILE` and `<node pkg= type=>` look (for hints)."""
        return [name for d in self._resource_dirs(pkg) for name in self._index(d)]

    def _resource_dirs(self, pkg: str) -> list[str]:
        """Where roslib's find_resource looks, in order: catkin lib/libexec/share dirs, then the package."""
        pkg_path = self.get_path(pkg)  # the package must exist, even when a catkin space has it
        return self.catkin_dirs(pkg, ("libexec", "share")) + [pkg_path]

    def find_node(self, pkg: str, node_type: str) -> str:
        """The executable for `<node pkg= type=>`: first file named `type` with user r+x bits.

        Where no package `rosbag` is found, rosbag's record and play are ours (`BAG_MAIN`)."""
        key = (pkg, node_type)
        cached = self._nodes.get(key)
        if cached is not None:
            return cached
        try:
            dirs = self._resource_dirs(pkg)
        except PackageNotFound:
            if (pkg, node_type) in BUILTIN_NODES:
                return BAG_MAIN
            raise
        not_executable = None  # the first file of that name without the x bit, for the error
        for d in dirs:
            for candidate in self._named(d, node_type):
                try:
                    mode = os.stat(candidate).st_mode
                except OSError:
                    continue  # a dangling symlink is no executable
                if mode & _USER_RX == _USER_RX:
                    found = os.path.abspath(candidate)
                    self._nodes[key] = found
                    return found
                if not_executable is None and stat.S_ISREG(mode):
                    not_executable = os.path.abspath(candidate)
        hint = "" if not_executable else did_you_mean(node_type, (
            name for d in self._resource_dirs(pkg) for name, paths in self._index(d).items()
            if any(os.path.isfile(p) and os.access(p, os.X_OK) for p in paths)))
        raise ExecutableNotFound(pkg, node_type, not_executable, hint)

    def find_launch_file(self, pkg: str, filename: str) -> str | None:
        """`launch PKG FILE`: the one file called FILE in the package (or its catkin dirs).

        None when there is none; raises PackageNotFound for an unknown package and
        MultipleResources when the name is ambiguous, as roslaunch does.
        """
        matches: list[str] = []
        for d in self._resource_dirs(pkg):
            for m in self._named(d, filename):
                m = os.path.abspath(m)
                if m not in matches:
                    matches.append(m)
        if len(matches) > 1:
            raise MultipleResources(pkg, filename, matches)
        return matches[0] if matches else None

    def find_resource(self, pkg: str, rel: str = "") -> str:
        """What `$(find pkg)rel` resolves to, `rel` being the text up to the next space.

        roslaunch's order: an executable `basename(rel)` in the first catkin lib/libexec dir
        of the package, an executable `<pkg dir>/rel`, an existing `<catkin share>/pkg/rel`,
        else `<pkg dir>/rel` whether it exists or not. Raises PackageNotFound.
        """
        path = rel.replace("\\", "/")
        if path.startswith("/"):
            path = path[1:]
        if path:
            libexec = self.catkin_dirs(pkg, ("libexec",))
            if libexec:
                hit = _executable_file(os.path.join(libexec[0], os.path.basename(path)))
                if hit:
                    return hit
            hit = _executable_file(os.path.join(self.get_path(pkg), path))
            if hit:
                return hit
            share = self.catkin_dirs(pkg, ("share",), path=path, first_match_only=True)
            if share:
                return share[0]
        pkg_path = self.get_path(pkg)
        return os.path.join(pkg_path, path) if path else pkg_path


def _executable_file(path: str) -> str | None:
    return path if os.path.isfile(path) and os.access(path, os.X_OK) else None
