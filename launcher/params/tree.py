"""The parameter tree: nested dicts with rosmaster's exact get/set/has/delete/names/search rules.

Keys are global graph names (`/a/b/c`); empty segments are ignored, so
`/a//b/` and `/a/b` are the same key. A dict value *is* a namespace: setting
one replaces whatever was there (no merge), setting a key below a scalar
turns the scalar into a namespace, and deleting the last child leaves an
empty namespace behind. Lists are leaves: the tree never descends into them.
"""

from __future__ import annotations

from typing import Any, Iterator

SEP = "/"


class ParamTree:
    """rosmaster's ParamDictionary semantics, without locks (one event loop owns it)."""

    __slots__ = ("root", "shape_version")

    def __init__(self, root: dict | None = None):
        self.root: dict[str, Any] = {} if root is None else root
        # bumped whenever the set of names may have changed (not when a leaf just gets a new
        # scalar value): lets a server cache what it derives from names() (change the tree
        # through these methods only)
        self.shape_version = 0

    @staticmethod
    def _parts(key: str) -> list[str]:
        return [p for p in key.split(SEP) if p]

    def get(self, key: str) -> Any:
        """The value (a dict for a namespace, `/` = whole tree); KeyError if not set."""
        val: Any = self.root
        if key == SEP:
            return val
        # like rosmaster, the first segment is skipped: it is "" for a global key (and a
        # relative key, which only a relative caller id can produce, reads from the root)
        for part in key.split(SEP)[1:]:
            if not part:
                continue
            if type(val) is not dict:
                raise KeyError(key)
            val = val[part]
        return val

    def has(self, key: str) -> bool:
        try:
            self.get(key)
            return True
        except KeyError:
            return False

    def set(self, key: str, value: Any) -> None:
        """Store `value` at `key` (by reference). `/` takes a dict only: TypeError otherwise."""
        if key == SEP:
            if type(value) is not dict:
                raise TypeError("cannot set root of parameter tree to non-dictionary")
            self.root = value
            self.shape_version += 1
            return
        parts = self._parts(key)
        if not parts:
            raise IndexError("no name in key [%s]" % key)  # "//": what rosmaster raises too
        d = self.root
        for part in parts[:-1]:
            nxt = d.get(part)
            if type(nxt) is not dict:
                # a scalar in the way silently becomes a namespace, as in rosmaster
                nxt = d[part] = {}
                self.shape_version += 1
            d = nxt
        last = parts[-1]
        old = d.get(last, d)  # d itself stands for "missing"
        if old is d or type(old) is dict or type(value) is dict:
            self.shape_version += 1
        d[last] = value

    def delete(self, key: str) -> None:
        """Remove `key` and everything below it; KeyError if not set (and always for `/`)."""
        if key == SEP:
            raise KeyError("cannot delete root of parameter tree")
        parts = self._parts(key)
        if not parts:
            raise IndexError("no name in key [%s]" % key)
        d: Any = self.root
        for part in parts[:-1]:
            if type(d) is not dict or part not in d:
                raise KeyError(key)
            d = d[part]
        if type(d) is not dict or parts[-1] not in d:
            raise KeyError(key)
        del d[parts[-1]]
        self.shape_version += 1

    def names(self) -> list[str]:
        """Every leaf as a global name, depth first in insertion order; empty namespaces are not listed."""
        return [name for name, _ in self.iter_leaves()]

    def iter_leaves(self) -> Iterator[tuple[str, Any]]:
        """(global name, value) for every leaf, in `names()` order."""
        todo: list[tuple[str, Iterator]] = [(SEP, iter(self.root.items()))]
        while todo:
            prefix, it = todo[-1]
            for k, v in it:
                name = _ns_join(prefix, k)
                if type(v) is dict:
                    todo.append((name, iter(v.items())))
                    break
                yield name, v
            else:
                todo.pop()

    def search(self, ns: str, key: str) -> str | None:
        """searchParam: the first partial match of `key` from `ns` (a caller id) up to `/`.

        Only the first segment of a relative key is looked for; the caller's own
        private namespace (`ns/key`) is tried first. ValueError for a private key
        or a relative `ns`, as rosmaster raises.
        """
        if not key or key[0] == "~":
            raise ValueError("invalid key")
        if not ns or ns[0] != SEP:
            raise ValueError("namespace must be global")
        if key[0] == SEP:
            return key if self.has(key) else None
        key_parts = self._parts(key)
        if not key_parts:
            raise ValueError("invalid key")
        first = key_parts[0]
        base = ns if ns.endswith(SEP) else ns + SEP
        if self.has(base + first):
            return base + key
        namespaces = self._parts(ns)
        for i in range(1, len(namespaces) + 1):
            head = namespaces[:-i]
            if self.has(SEP + SEP.join(head + [first])):
                return SEP + SEP.join(head + [key])
        return None


def _ns_join(ns: str, name: str) -> str:
    # rosgraph.names.ns_join: a global or private name is not joined (a dict key "/x" lists as "/x")
    if name[:1] in ("/", "~"):
        return name
    if ns[-1] == SEP:
        return ns + name
    return ns + SEP + name


def copy_tree(value: Any) -> Any:
    """A copy of a value whose dicts (namespaces) are fresh, so that later sets cannot alias it."""
    if type(value) is dict:
        return {k: copy_tree(v) for k, v in value.items()}
    return value
