"""A loading scope (roslaunch's LoaderContext): namespace, args, remaps, env, private `~params`.

Every `<group>`, `<include>` and `<node>` opens a child scope. The copy rules
are roslaunch's, including the odd ones users rely on: args and anonymous
names are copied into a child (a child's declarations never leak out), remaps
and `<env>` are inherited, and the list of launch-level `~params` is *shared*
with the child when it is non-empty (so a `~param` declared inside an
`<include>` also reaches later nodes of the including file).
"""

from __future__ import annotations

import functools

from launcher.model.names import PRIV_NAME, SEP, make_global_ns, ns_join
from launcher.model.names import canonicalize_name as canonical
from launcher.model.names import is_legal_name as _is_legal_name
from launcher.xml.substitution import LoadBudget, SubstitutionScope

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Mapping

# names.is_legal_name, remembered: a launch tree checks the same few names (remaps, node names)
# thousands of times; a pure function of the name
is_legal_name = functools.lru_cache(maxsize=8192)(_is_legal_name)


class ScopeError(ValueError):
    """An invalid namespace, remap or arg declaration; the loader adds file and line."""


def add_remap_to(remaps: list[tuple[str, str]], src: str, dst: str) -> None:
    """Add a remap (checked, canonical) to `remaps`; a remap of the same name is replaced, at the end."""
    src, dst = canonical(src), canonical(dst)
    if not src or not dst:
        raise ScopeError("remap from/to attributes cannot be empty")
    if not is_legal_name(src):
        raise ScopeError("remap from [%s] is not a valid ROS name" % src)
    if not is_legal_name(dst):
        raise ScopeError("remap to [%s] is not a valid ROS name" % dst)
    for r in remaps:
        if r[0] == src:
            remaps[:] = [r for r in remaps if r[0] != src]
            break
    remaps.append((src, dst))


def global_ns(ns: str) -> str:
    try:
        return make_global_ns(ns or SEP)
    except ValueError:
        raise ScopeError("cannot use the private name [%s] as a namespace" % ns) from None


class Scope(SubstitutionScope):
    __slots__ = ("ns", "parent", "remaps", "_remap_cache", "params", "env_args", "arg_docs", "arg_names",
                 "include_args", "include_arg_docs", "pass_all_args", "args_passed",
                 "source", "include_chain", "policy")

    def __init__(self, ns: str, filename: str, *, environ: Mapping[str, str],
                 find_package: Callable[[str], str], find_resource: Callable[[str, str], str],
                 args: dict[str, str] | None = None, used_args: set[str] | None = None,
                 budget: LoadBudget | None = None):
        super().__init__(args if args is not None else {}, {}, filename, environ, find_package, find_resource,
                         used_args, budget)
        self.ns = global_ns(ns)
        self.parent: Scope | None = None
        self.remaps: list[tuple[str, str]] = []
        self._remap_cache: tuple[tuple[str, str], ...] | None = None
        self.params: list[tuple[str, Any, str, int]] = []  # (key, value, file, line) of ~params
        self.env_args: list[tuple[str, str]] = []
        self.arg_docs: dict[str, tuple[str | None, str | None]] = {}
        self.arg_names: list[str] = []
        # while the <arg> children of an <include> are read, declarations go to these
        self.include_args: dict[str, str] | None = None
        self.include_arg_docs: dict[str, tuple[str | None, str | None]] | None = None
        self.pass_all_args = False
        self.args_passed: list[str] = []
        self.source = filename  # the file whose elements are being read (for errors)
        self.include_chain: tuple[tuple[str, int], ...] = ()
        # the supervision defaults (NodePolicy field -> value) that <launch>, <group> and <include>
        # give the nodes inside; None when none is set. Never changed in place: a scope that sets
        # defaults gets a new dict, so a child may share its parent's.
        self.policy: dict[str, Any] | None = None

    def _child_ns(self, ns: str | None) -> str:
        """The namespace a child scope with `ns=` gets (global, `~`, or relative to ours)."""
        if not ns:
            return self.ns
        if ns[0] == SEP or ns == PRIV_NAME:
            return ns
        return ns_join(self.ns, ns)

    def child(self, ns: str | None) -> Scope:
        child_ns = self._child_ns(ns)
        c = Scope.__new__(Scope)
        c.args = dict(self.args)
        c.anon = dict(self.anon)
        c.filename = self.filename
        c.environ = self.environ
        c.find_package = self.find_package
        c.find_resource = self.find_resource
        c.used_args = self.used_args
        c.budget = self.budget
        c.ns = self.ns if child_ns is self.ns else global_ns(child_ns)
        c.parent = self
        c.remaps = []
        c._remap_cache = None
        c.params = self.params if self.params else []
        c.env_args = self.env_args[:]
        c.arg_docs = dict(self.arg_docs)
        c.arg_names = self.arg_names[:]
        c.include_args = None
        c.include_arg_docs = None
        c.pass_all_args = False
        c.args_passed = []
        c.source = self.source
        c.include_chain = self.include_chain
        c.policy = self.policy
        return c

    def node_child(self, ns: str | None) -> Scope:
        """A child for a <node>'s namespace and params: as child(), but sharing what a node's children never
        change (args, arg declarations, env), which makes a 1000-node launch much cheaper."""
        child_ns = self._child_ns(ns)
        c = Scope.__new__(Scope)
        c.args = self.args
        c.anon = dict(self.anon) if self.anon else {}
        c.filename = self.filename
        c.environ = self.environ
        c.find_package = self.find_package
        c.find_resource = self.find_resource
        c.used_args = self.used_args
        c.budget = self.budget
        c.ns = self.ns if child_ns is self.ns else global_ns(child_ns)
        c.parent = self
        c.remaps = []
        c._remap_cache = None
        c.params = self.params if self.params else []
        c.env_args = self.env_args
        c.arg_docs = self.arg_docs
        c.arg_names = self.arg_names
        c.include_args = None
        c.include_arg_docs = None
        c.pass_all_args = False
        c.args_passed = []
        c.source = self.source
        c.include_chain = self.include_chain
        c.policy = self.policy
        return c

    def include_child(self, ns: str | None, filename: str) -> Scope:
        c = self.child(ns)
        c.arg_names = []
        c.filename = filename
        c.include_args = {}
        c.include_arg_docs = {}
        return c

    # -- private params -------------------------------------------------
    def add_param(self, key: str, value: Any, filename: str, line: int) -> None:
        key = canonical(key)
        params = self.params
        for p in params:
            if p[0] == key:  # a redefinition replaces the first one, at the end
                params[:] = [p for p in params if p[0] != key]
                break
        params.append((key, value, filename, line))

    # -- remaps ---------------------------------------------------------
    def add_remap(self, src: str, dst: str) -> None:
        add_remap_to(self.remaps, src, dst)
        self._remap_cache = None

    def remap_args_with(self, own: list[tuple[str, str]]) -> tuple[tuple[str, str], ...]:
        """remap_args() of a child scope whose own remaps are `own` (a <node>'s <remap> children)."""
        inherited = self.remap_args()
        if not own:
            return inherited
        names = {r[0] for r in own}
        return tuple([r for r in inherited if r[0] not in names] + own)

    def remap_args(self) -> tuple[tuple[str, str], ...]:
        """Inherited remaps first (minus those redefined here), then this scope's, in order."""
        # a scope's parents do not change while it is alive (document order), so cache until our own change
        if self._remap_cache is not None:
            return self._remap_cache
        if self.parent is None:
            out = tuple(self.remaps)
        elif not self.remaps:
            out = self.parent.remap_args()
        else:
            own = {r[0] for r in self.remaps}
            out = tuple([r for r in self.parent.remap_args() if r[0] not in own] + self.remaps)
        self._remap_cache = out
        return out

    # -- args -------------------------------------------------------------
    def add_arg(self, name: str, default: str | None = None, value: str | None = None,
                doc: str | None = None) -> None:
        if name in self.arg_names:
            if not self.pass_all_args:
                raise ScopeError("arg '%s' has already been declared" % name)
        else:
            self.arg_names.append(name)
        if self.include_args is None:
            args, docs = self.args, self.arg_docs
        else:
            args, docs = self.include_args, self.include_arg_docs
            assert docs is not None
        if value is not None:
            if name in args and not self.pass_all_args:
                raise ScopeError("cannot override arg '%s', which has already been set" % name)
            args[name] = value
        elif default is not None:
            if name not in args:
                args[name] = default
        if not value:
            docs[name] = (doc, default)

    def start_include(self) -> None:
        """The `<include>`'s own `<arg>`s are read: check them and make them the included file's args."""
        args = self.include_args or {}
        for name in self.arg_names:
            if name not in args:
                raise ScopeError("include args must have declared values (arg '%s' has no value)" % name)
        self.args_passed = list(args)
        self.arg_names = []
        self.args = args
        self.arg_docs = self.include_arg_docs or {}
        # roslaunch swaps in a fresh resolve dict: anonymous names start over in the included file
        self.anon = {}
        self.include_args = None
        self.include_arg_docs = None

    def unused_include_args(self) -> list[str]:
        return [a for a in self.args_passed if a not in self.arg_names]
