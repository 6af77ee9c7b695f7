"""The launch XML tags: `launch node test include group arg param rosparam remap env machine`.

`XmlLoader` walks the documents in document order, exactly as roslaunch's
XmlLoader does (same scopes, same checks, same quirks), and collects a
`LaunchConfig`. Every problem is a `LaunchError` with the file and line of the
element at fault and the chain of `<include>`s that led there; things
roslaunch silently accepts (unknown tags and attributes, a parameter under
another parameter) are accepted with a warning that says where they are.
"""

from __future__ import annotations

import os
import re
import sys

from launcher.model.config import LaunchConfig, Machine, Node, NodePolicy, Param, new_param
from launcher.model.errors import SHOWN_CHARS, LaunchError, shorten
from launcher.model.names import CALLER_ID, PRIV_NAME, SEP, make_global_ns, ns_join, resolve_name
from launcher.params.values import PARAM_TYPES, auto_value, convert_value
from launcher.params.yamlcache import YamlCache
from launcher.workspace.roshome import ros_home
from launcher.model.suggest import did_you_mean, near_file
from launcher.xml.arguments import load_mappings, root_namespace
from launcher.xml.document import element_text, read_launch
from launcher.xml.policy import (POLICY_ATTR_NAMES, RESPAWN_ONLY, PolicyError, read_policy, resolve_wait_names,
                                 resolve_watch_topics)
from launcher.xml.scope import Scope, ScopeError, add_remap_to, canonical, is_legal_name
from launcher.model.names import AnonNames
from launcher.xml.substitution import ArgNotSet, LoadBudget, SubstitutionError, resolve

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Iterable, Mapping

    from launcher.xml.commands import CommandError, CommandParam

# roslaunch's per-tag attribute lists, plus our supervision extensions (xml/policy.py) where they
# apply; anything else is warned about
ROSLAUNCH_NODE_ATTRS = frozenset(("pkg", "type", "machine", "name", "args", "output", "respawn", "respawn_delay",
                                  "cwd", "ns", "clear_params", "launch-prefix", "required", "if", "unless"))
NODE_ATTRS = ROSLAUNCH_NODE_ATTRS | POLICY_ATTR_NAMES
TEST_ATTRS = ROSLAUNCH_NODE_ATTRS | {"test-name", "time-limit", "retry"}  # (rostest runs tests: no policy)
PARAM_ATTRS = frozenset(("name", "value", "type", "textfile", "binfile", "command", "if", "unless"))
ROSPARAM_ATTRS = frozenset(("command", "ns", "file", "param", "subst_value", "if", "unless"))
ARG_ATTRS = frozenset(("name", "value", "default", "doc", "if", "unless"))
MACHINE_ATTRS = frozenset(("name", "address", "env-loader", "ssh-port", "user", "password", "default",
                           "timeout", "if", "unless"))
REMAP_ATTRS = frozenset(("from", "to", "if", "unless"))
ENV_ATTRS = frozenset(("name", "value", "if", "unless"))
INCLUDE_ATTRS = frozenset(("file", "ns", "clear_params", "pass_all_args", "if", "unless")) | POLICY_ATTR_NAMES
GROUP_ATTRS = frozenset(("ns", "clear_params", "if", "unless")) | POLICY_ATTR_NAMES
LAUNCH_ATTRS = frozenset(("deprecated", "if", "unless")) | POLICY_ATTR_NAMES

TEST_TIME_LIMIT_DEFAULT = 60.0
MACHINE_TIMEOUT_DEFAULT = 10.0
CORE_NODE_NAMES = ("/rosout",)
MAX_INCLUDE_DEPTH = 100  # roscore.xml's node, which every launch but --dump-params loads

_MULTISLASH = re.compile("//+")


class XmlLoader:
    """One load: files + command-line args -> LaunchConfig."""

    def __init__(self, *, environ: Mapping[str, str], packages: Any, argv: Iterable[str] = (),
                 args_only: bool = False, core: bool = True,
                 warn: Callable[[str], None] | None = None, anon_names: AnonNames | None = None):
        self.environ = environ
        self.packages = packages
        self.argv = list(argv)
        self._warn_cb = warn
        self.warnings: list[str] = []
        self.cli_args = load_mappings(self.argv, warn=self._warn_plain)
        self.root_ns = root_namespace(self.argv, environ)
        self.args_only = args_only
        self.nodes: list[Node] = []
        self.tests: list[Node] = []
        self.params: dict[str, Param] = {}
        self.clear_params: list[str] = []
        self.machines: dict[str, Machine] = {}
        self.files: list[str] = []
        self.yaml_files: dict[str, None] = {}  # <rosparam file=...> loaded, in order, once each
        self.rosparam_commands: list[tuple[str, str, str | None]] = []
        self._commands: list[CommandParam] = []  # <param command=...>, run at the end (xml/commands.py)
        self.node_names: set[str] = set(CORE_NODE_NAMES) if core else set()
        self.root_scope: Scope | None = None
        # launch-level ~params, to warn about those that no later node picks up
        self._private_params: dict[tuple[str, str, int], tuple[tuple[str, int], ...]] = {}
        self._used_private: set[tuple[str, str, int]] = set()
        self._declared_args: set[str] = set()
        self._used_args: set[str] = set()  # what $(arg) read, in every scope (see _undeclared_cli_args)
        self._clean_ns: str | None = None  # see _add_param
        self._key_lengths: set[int] = set()  # the lengths of the keys in self.params (see _add_param)
        self._realpaths: dict[str, str] = {}
        # the text all substitutions of this load may make; the anonymous names of the run it is a load of
        self._budget = LoadBudget(anon_names=anon_names)
        self._found_resources: dict[tuple[str, str], str] = {}
        # the rosparam module's YAML tags (deg(), !degrees, ...) exist only after the first <rosparam>
        self._ros_yaml = False
        self.yaml_cache = YamlCache(ros_home(environ))  # saved by xml.load once the files are read

    # ------------------------------------------------------------------ output
    def config(self) -> LaunchConfig:
        self._run_commands()
        self._late_warnings()
        seen: dict[str, None] = {}
        for f in self.files:
            seen.setdefault(os.path.abspath(f))
        return LaunchConfig(nodes=tuple(self.nodes), tests=tuple(self.tests), params=self.params,
                            clear_params=tuple(self.clear_params), machines=self.machines,
                            files=tuple(seen), warnings=tuple(self.warnings),
                            rosparam_commands=tuple(self.rosparam_commands), yaml_files=tuple(self.yaml_files))

    def _late_warnings(self) -> None:
        """What roslaunch silently ignores and can only be seen once everything is loaded."""
        for (key, pfile, pline), chain in self._private_params.items():
            if (key, pfile, pline) not in self._used_private:
                text = ("%s:%d: private parameter [%s] is not set for any node: a launch-level ~param only "
                        "applies to <node>s that follow it in the same scope" % (pfile, pline, key))
                for f, ln in chain:
                    text += "\n  included from %s:%d" % (f, ln)
                self._warn_plain(text)
        self._private_params.clear()
        self._undeclared_cli_args()  # (an unknown machine is the run's error: plan.Plan.check_nodes)

    def _undeclared_cli_args(self) -> None:
        """roslaunch silently ignores `name:=value` for an arg no file declares: say so (a typo, usually)."""
        for a, value in self.cli_args.items():
            # roslaunch lets $(arg x) read an undeclared command-line arg: that counts as used
            if not a.startswith("__") and a not in self._declared_args and a not in self._used_args:
                hint = did_you_mean(a, self._declared_args)
                self._warn_plain("command-line argument [%s:=%s] is not declared by an <arg> in the launch "
                                 "file(s) and is ignored%s" % (a, value, " (%s)" % hint if hint else ""))

    # ------------------------------------------------------------------ errors
    def _warn_plain(self, msg: str) -> None:
        self.warnings.append(msg)
        if self._warn_cb:
            self._warn_cb(msg)

    def _warn(self, scope: Scope, el: Any, msg: str) -> None:
        line = getattr(el, "sourceline", None)
        where = "%s:%d: " % (scope.source, line) if line else "%s: " % scope.source
        text = where + _shortened(msg)
        for f, ln in scope.include_chain:
            text += "\n  included from %s:%d" % (f, ln)
        self._warn_plain(text)

    def _fail(self, scope: Scope, el: Any, msg: str) -> LaunchError:
        return LaunchError(_shortened(msg), scope.source, getattr(el, "sourceline", None), scope.include_chain)

    def _sub(self, text: str | None, scope: Scope, el: Any) -> str | None:
        """Resolve substitution args, turning their errors into located LaunchErrors."""
        if not text or "$" not in text:
            return text
        try:
            return resolve(text, scope)
        except ArgNotSet as e:
            raise self._fail(scope, el, self._arg_not_set(e.name, scope)) from None
        except SubstitutionError as e:
            raise self._fail(scope, el, "%s" % e) from None
        except LaunchError as e:
            if e.filename:
                raise
            raise self._fail(scope, el, e.message) from None

    def _arg_not_set(self, name: str, scope: Scope) -> str:
        if name not in scope.arg_names:
            hint = did_you_mean(name, scope.arg_names)
            return ("arg '%s' is not defined%s: declare it with <arg name=\"%s\" default=\"...\"/> before using "
                    "$(arg %s)" % (name, " (%s)" % hint if hint else "", name, name))
        if scope.include_chain:
            return ("arg '%s' is required by this included file: pass it with <arg name=\"%s\" value=\"...\"/> "
                    "inside the <include>" % (name, name))
        return "arg '%s' is required: pass %s:=value on the command line" % (name, name)

    def _attr(self, el: Any, name: str, scope: Scope) -> str | None:
        v = el.attrib.get(name)
        if not v or "$" not in v:
            return v
        return self._sub(v, scope, el)

    def _reqd(self, el: Any, name: str, scope: Scope) -> str:
        v = el.attrib.get(name)
        if v is None:
            raise self._fail(scope, el, "<%s> tag is missing required attribute: '%s'" % (el.tag, name))
        return v if "$" not in v else self._sub(v, scope, el)  # type: ignore[return-value]

    def _check_attrs(self, el: Any, scope: Scope, allowed: frozenset[str]) -> None:
        keys = el.attrib
        if allowed.issuperset(keys):  # the usual case, checked in C
            return
        for a in keys:
            if a not in allowed:
                self._warn(scope, el, "unknown <%s> attribute '%s' (ignored)" % (el.tag, a))

    def _bool(self, v: str | None, default: bool, label: str, scope: Scope, el: Any) -> bool:
        if v is None:
            return default
        low = v.lower()
        if low == "true":
            return True
        if low == "false":
            return False
        if not v:
            raise self._fail(scope, el, "bool value for %s must be non-empty" % label)
        raise self._fail(scope, el, "invalid bool value for %s: %s" % (label, v))

    def _if_unless(self, el: Any, scope: Scope) -> bool:
        """True if the element is to be processed (its if/unless say so)."""
        get = el.attrib.get
        if get("if") is None and get("unless") is None:
            return True
        if_val = self._attr(el, "if", scope)
        unless_val = self._attr(el, "unless", scope)
        if if_val is not None and unless_val is not None:
            raise self._fail(scope, el, "cannot set both 'if' and 'unless' on the same tag")
        if if_val is not None:
            return self._condition(if_val, "if", scope, el)
        return not self._condition(unless_val or "", "unless", scope, el)

    def _condition(self, v: str, label: str, scope: Scope, el: Any) -> bool:
        low = v.lower().strip()
        if low in ("true", "1"):
            return True
        if low in ("false", "0"):
            return False
        raise self._fail(scope, el, "invalid value for %s=: [%s] is not a 'bool' type "
                                    "(use true, false, 1 or 0)" % (label, v))

    def _policy(self, el: Any, scope: Scope) -> dict[str, Any]:
        """The supervision fields an element's extension attributes set ({} if none)."""
        try:
            return read_policy(el.attrib, lambda text: self._sub(text, scope, el) or "")
        except PolicyError as e:
            raise self._fail(scope, el, "Invalid <%s> tag: %s" % (el.tag, e)) from None

    def _scope_policy(self, el: Any, scope: Scope, inner: Scope) -> None:
        """A <launch>, <group> or <include> that sets extension attributes (read in `scope`): defaults for
        the nodes of `inner`, the scope it opens."""
        if POLICY_ATTR_NAMES.isdisjoint(el.attrib.keys()):
            return
        fields = self._policy(el, scope)
        inner.policy = {**inner.policy, **fields} if inner.policy else fields

    # ------------------------------------------------------------------ files
    def load_file(self, filename: str) -> None:
        doc = read_launch(filename)
        launch = doc.launch
        self.files.append(filename)
        scope = Scope(self.root_ns, filename, environ=self.environ,
                      find_package=self._find_package, find_resource=self._find_resource,
                      args=dict(self.cli_args), used_args=self._used_args, budget=self._budget)
        self.root_scope = scope
        try:
            self._launch_tag(launch, scope)
            if not self.args_only:
                for m in doc.masters:
                    self._warn(scope, m, "ignoring defunct <master /> tag")
            self._recurse(launch, scope, None)
        except RecursionError as e:
            # the walk follows the nesting of <group>s and <include>s (expat has no depth limit);
            # the stack is unwound here, so the error can be made
            where = getattr(e, "element", None)
            if where is None:
                raise LaunchError("elements or includes are nested too deeply (Python's recursion limit)",
                                  filename) from None
            at_scope, el = where
            raise self._fail(at_scope, el, "elements or includes are nested too deeply around this <%s> "
                                           "(Python's recursion limit)" % el.tag) from None

    def _launch_tag(self, launch: Any, scope: Scope) -> None:
        self._check_attrs(launch, scope, LAUNCH_ATTRS)
        if not self._if_unless(launch, scope):
            return
        deprecated = launch.attrib.get("deprecated")
        if deprecated:
            self._warn(scope, launch, "DEPRECATED: %s" % deprecated)
        if not self.args_only:
            self._scope_policy(launch, scope, scope)

    def _realpath(self, filename: str) -> str:
        """os.path.realpath, once per file name in a load (include cycle checks ask for each level)."""
        real = self._realpaths.get(filename)
        if real is None:
            real = self._realpaths[filename] = os.path.realpath(filename)
        return real

    def _find_package(self, pkg: str) -> str:
        return self.packages.get_path(pkg)

    def _find_resource(self, pkg: str, rel: str) -> str:
        # once per distinct `$(find pkg)path` in a load: each is up to three file checks, and a long
        # attribute can repeat the same one a hundred thousand times
        key = (pkg, rel)
        found = self._found_resources.get(key)
        if found is None:
            found = self._found_resources[key] = self.packages.find_resource(pkg, rel)
        return found

    # ------------------------------------------------------------------ walk
    def _recurse(self, parent_el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        """Process the children of `parent_el` in order; returns the default machine after them."""
        handlers = self.tag_handlers
        el = None
        try:
            for el in parent_el:
                tag = el.tag
                if tag == "arg":  # (checks its own if/unless; the one tag read with args_only)
                    self._arg_tag(el, scope)
                    continue
                if self.args_only:
                    continue
                handler = handlers.get(tag)
                if handler is None:
                    if tag != "master":  # (<master> is warned about once per file)
                        self._warn(scope, el, "unrecognized tag <%s> (ignored)" % tag)
                    continue
                get = el.attrib.get
                # most elements have neither if nor unless: decided here without a call
                if (get("if") is None and get("unless") is None) or self._if_unless(el, scope):
                    default_machine = handler(self, el, scope, default_machine)
        except RecursionError as e:
            # the innermost element being read when the nesting met Python's limit, for load_file's error
            if getattr(e, "element", None) is None and el is not None:
                e.element = (scope, el)  # type: ignore[attr-defined]
            raise
        return default_machine

    # Each handler takes (element, scope, default machine) and returns the default machine for
    # the elements that follow (only <machine default="true"> and what <group>/<include> contain change it).
    def _node_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._node_tag(el, scope, default_machine, is_test=False)
        return default_machine

    def _test_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._node_tag(el, scope, default_machine, is_test=True)
        return default_machine

    def _param_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._param_tag(el, scope)
        return default_machine

    def _rosparam_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._rosparam_tag(el, scope)
        return default_machine

    def _env_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._env_tag(el, scope)
        return default_machine

    def _remap_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        src, dst = self._remap_tag(el, scope)
        self._add_remap(scope, src, dst, el)
        return default_machine

    def _group_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._check_attrs(el, scope, GROUP_ATTRS)
        child = self._ns_clear_params(el, scope, "group")
        child.params = list(child.params)
        self._scope_policy(el, scope, child)
        return self._recurse(el, child, default_machine)

    def _machine_element(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        m, is_default = self._machine_tag(el, scope)
        return m if is_default else default_machine

    # ------------------------------------------------------------------ ns + clear_params
    def _ns_clear_params(self, el: Any, scope: Scope, kind: str, node_name: str | None = None,
                         include_file: str | None = None) -> Scope:
        if el.attrib.get("ns") is not None:
            ns = self._attr(el, "ns", scope)
            if not ns:
                raise self._fail(scope, el, "<%s> tag has an empty 'ns' attribute" % el.tag)
        else:
            ns = None
        try:
            if include_file is not None:
                child = scope.include_child(ns, include_file)
            elif kind == "node":
                # a node only reads its namespace scope (to make its params' scope): without ns=,
                # that is the enclosing scope itself, no copy needed
                child = scope if ns is None else scope.node_child(ns)
            else:
                child = scope.child(ns)
        except ScopeError as e:
            raise self._fail(scope, el, str(e)) from None
        clear = el.attrib.get("clear_params")
        if clear and "$" in clear:
            clear = self._sub(clear, scope, el)
        if clear and self._bool(clear, False, "clear_params", scope, el):
            if kind == "node":
                if not node_name:
                    raise self._fail(scope, el, "<%s> tag must have a 'name' attribute to use 'clear_params' "
                                                "attribute" % el.tag)
                try:
                    self.clear_params.append(make_global_ns(ns_join(child.ns, node_name)))
                except ValueError:
                    raise self._fail(scope, el, "Invalid <%s> tag: cannot clear the parameters of the private "
                                                "name [%s]" % (el.tag, node_name)) from None
            else:
                if not ns:
                    raise self._fail(scope, el, "'ns' attribute must be set in order to use 'clear_params'")
                self.clear_params.append(child.ns)
        return child

    # ------------------------------------------------------------------ <arg>
    def _arg_tag(self, el: Any, scope: Scope) -> None:
        if not self._if_unless(el, scope):
            return
        self._check_attrs(el, scope, ARG_ATTRS)
        name = self._reqd(el, "name", scope)
        value = self._attr(el, "value", scope)
        default = self._attr(el, "default", scope)
        doc = self._attr(el, "doc", scope)
        if value is not None and default is not None:
            raise self._fail(scope, el, "<arg> tag must have one and only one of value/default.")
        self._declared_args.add(name)
        try:
            scope.add_arg(name, default=default, value=value, doc=doc)
        except ScopeError as e:
            raise self._fail(scope, el, str(e)) from None

    # ------------------------------------------------------------------ <remap>, <env>
    def _remap_tag(self, el: Any, scope: Scope) -> tuple[str, str]:
        attrib = el.attrib
        if not REMAP_ATTRS.issuperset(attrib):
            self._check_attrs(el, scope, REMAP_ATTRS)
        src = attrib.get("from")
        dst = attrib.get("to")
        if src is None or dst is None:
            raise self._fail(scope, el, "<remap> tag is missing required from/to attributes")
        if "$" in src:
            src = self._sub(src, scope, el)
        if "$" in dst:
            dst = self._sub(dst, scope, el)
        return src or "", dst or ""

    def _add_remap(self, scope: Scope, src: str, dst: str, el: Any) -> None:
        try:
            scope.add_remap(src, dst)
        except ScopeError as e:
            raise self._fail(scope, el, "Invalid <remap> tag: %s" % e) from None

    def _env_tag(self, el: Any, scope: Scope) -> None:
        self._check_attrs(el, scope, ENV_ATTRS)
        if el.attrib.get("name") is None or el.attrib.get("value") is None:
            raise self._fail(scope, el, "<env> tag is missing required name/value attributes")
        name = self._attr(el, "name", scope)
        value = self._attr(el, "value", scope)
        if not name:
            raise self._fail(scope, el, "Invalid <env> tag: 'name' attribute must be non-empty")
        scope.env_args.append((name, value or ""))

    # ------------------------------------------------------------------ <param>
    def _param_tag(self, el: Any, scope: Scope, force_local: bool = False) -> None:
        get = el.attrib.get
        keys = el.attrib
        if not PARAM_ATTRS.issuperset(keys):
            for a in keys:
                if a not in PARAM_ATTRS:
                    self._warn(scope, el, "unknown <param> attribute '%s' (ignored)" % a)
        ptype = get("type")
        ptype = ptype.lower().strip() if ptype else "auto"
        value = get("value")
        if ("textfile" in keys) + ("binfile" in keys) + ("command" in keys) + (value is not None) != 1:
            raise self._fail(scope, el, "<param> tag must have one and only one of value/textfile/binfile/command.")
        raw_name = get("name")
        if raw_name is None:
            raise self._fail(scope, el, "<param> tag is missing required attribute: 'name'")
        name = raw_name.strip()
        if "$" in name:
            name = self._sub(name, scope, el) or ""
        if value is not None:
            if "$" in value:
                value = self._sub(value, scope, el)
            value = value.strip()  # type: ignore[union-attr]
            if ptype == "auto":
                typed = auto_value(value)
            elif ptype == "str" or ptype == "string":
                typed = value  # (what convert_value does for these, without the calls)
            else:
                typed = self._convert(value, ptype, scope, el, name)
        else:
            typed = self._param_value(el, scope, name, ptype, None, self._sub(get("textfile"), scope, el),
                                      self._sub(get("binfile"), scope, el), self._sub(get("command"), scope, el))
        if force_local or name[:1] == "~":
            scope.add_param(name, typed, scope.source, el.sourceline or 0)
            if not force_local:
                self._private_params[(canonical(name), scope.source, el.sourceline or 0)] = scope.include_chain
        else:
            self._add_param(ns_join(scope.ns, name), typed, scope, el)

    def _known_type(self, ptype: str, scope: Scope, el: Any, name: str) -> None:
        """Refuse a `type=` roslaunch does not know, in its words. (`type=" "` is the type '' to roslaunch, though
        convert_value takes '' for auto.)"""
        if ptype not in PARAM_TYPES:
            raise self._fail(scope, el, "Invalid <param> tag [%s]: Unknown type '%s'" % (name, ptype))

    def _convert(self, text: str, ptype: str, scope: Scope, el: Any, name: str) -> Any:
        self._known_type(ptype, scope, el, name)
        if ptype == "yaml":
            # rosparam's angle tags exist only once a <rosparam> has been processed (an import side effect)
            return self._yaml(text, scope, el, angles=self._ros_yaml, what="<param> [%s]" % name)
        try:
            return convert_value(text, ptype)
        except ValueError as e:
            if ptype in ("int", "double"):
                msg = "value [%s] is not of type %s" % (text.strip(), ptype)
            else:
                msg = str(e)
            raise self._fail(scope, el, "Invalid <param> tag [%s]: %s" % (name, msg)) from None

    def _param_value(self, el: Any, scope: Scope, name: str, ptype: str, value: str | None,
                     textfile: str | None, binfile: str | None, command: str | None) -> Any:
        if value is not None:
            return self._convert(value.strip(), ptype, scope, el, name)
        if textfile is not None:
            try:
                with open(textfile, "r", encoding="utf-8") as f:
                    text = f.read()
            except (OSError, UnicodeDecodeError) as e:
                raise self._fail(scope, el, "Invalid <param> tag: cannot read textfile [%s]: %s"
                                 % (textfile, getattr(e, "strerror", None) or e)) from None
            return self._convert(text, ptype, scope, el, name)
        if binfile is not None:
            try:
                with open(binfile, "rb") as f:
                    return f.read()
            except OSError as e:
                raise self._fail(scope, el, "Invalid <param> tag: cannot read binfile [%s]: %s"
                                 % (binfile, e.strerror or e)) from None
        assert command is not None
        return self._command_param(command, name, ptype, scope, el)

    def _command_param(self, command: str, name: str, ptype: str, scope: Scope, el: Any) -> CommandParam:
        """A stand-in for the value, run with the others once the launch is read (xml/commands.py)."""
        # the type is refused now, whatever the command prints: roslaunch runs every command as it reads it and
        # refuses the type after, so also where a later tag overwrites the parameter or no node takes a private one,
        # which never run here
        self._known_type(ptype, scope, el, name)
        # (imported by the first <param command>: few launches have one)
        from launcher.xml.commands import CommandError, CommandParam

        def finish(outcome: str | CommandError) -> Any:
            if isinstance(outcome, CommandError):
                raise self._fail(scope, el, str(outcome))
            return self._convert(outcome, ptype, scope, el, name)
        pending = CommandParam(command, name, finish)
        self._commands.append(pending)
        return pending

    def _run_commands(self) -> None:
        """Run the command parameters whose parameter is still set (in file order), and put their values in."""
        if not self._commands:
            return  # (the usual case: no <param command>, and its module not imported)
        from launcher.xml.commands import CommandParam, run_all
        params = self.params
        live = {id(p.value) for p in params.values() if type(p.value) is CommandParam}
        pending = [c for c in self._commands if id(c) in live]
        self._commands.clear()
        if not pending:
            return
        terminal = sys.stderr if sys.stderr.isatty() else None
        run_all(pending, self.environ, terminal)
        for key, p in params.items():
            if type(p.value) is CommandParam:
                params[key] = p._replace(value=p.value.result)

    def _add_param(self, key: str, value: Any, scope: Scope, el: Any) -> None:
        if "//" in key or (key[-1:] == SEP and len(key) > 1):  # (canonical(), inline: nearly all keys are)
            key = canonical(key)
        params = self.params
        # a parameter under another parameter is only a config error in roslaunch: warn.
        # Parameters come in runs with the same namespace: once no prefix of a namespace is a
        # parameter, the next key in that namespace needs no new check (adding `ns/x` cannot make
        # a prefix of `ns` a parameter; every other way of adding params resets the check).
        # A parent can only be a parameter of the length of some parameter's key: slicing and
        # hashing every prefix of a key is quadratic in its length (a 100,000-segment name).
        ns_end = key.rfind(SEP)
        if ns_end <= 0 or key[:ns_end] != self._clean_ns:
            clean = True
            key_lengths = self._key_lengths
            i = -1  # (the position of each '/' but the last, from one split: a find() per '/' rescans the key)
            for part in key.split(SEP)[:-1]:
                i += len(part) + 1
                if i in key_lengths and i > 0:
                    parent = key[:i]
                    if parent in params:
                        clean = False
                        self._warn(scope, el, "parameter [%s] conflicts with parent parameter [%s]" % (key, parent))
            self._clean_ns = key[:ns_end] if clean and ns_end > 0 else None
        self._key_lengths.add(len(key))
        params[key] = new_param(key, value, scope.source, el.sourceline or 0)

    # ------------------------------------------------------------------ YAML
    def _yaml(self, text: str, scope: Scope, el: Any, *, angles: bool, what: str,
              yaml_file: str | None = None) -> Any:
        try:
            if yaml_file:
                return self.yaml_cache.load(text, filename=yaml_file, angles=angles)
            return self.yaml_cache.load(text, filename=scope.source, first_line=el.sourceline or 1, angles=angles)
        except LaunchError as e:  # (rosyaml.RosYamlError: a LaunchError, imported only when PyYAML is)
            if yaml_file:
                # the line is the YAML file's own; the chain says which tag loaded it
                chain = ((scope.source, el.sourceline or 0),) + scope.include_chain
                raise LaunchError(e.message, yaml_file, e.line, chain) from None
            line = e.line if (e.line and el.tag == "rosparam") else el.sourceline
            raise LaunchError("%s: %s" % (what, e.message), scope.source, line, scope.include_chain) from None

    # ------------------------------------------------------------------ <rosparam>
    def _rosparam_tag(self, el: Any, scope: Scope) -> None:
        self._check_attrs(el, scope, ROSPARAM_ATTRS)
        cmd, ns, file_, param, subst = (self._attr(el, a, scope) for a in
                                        ("command", "ns", "file", "param", "subst_value"))
        subst_value = self._bool(subst, False, "subst_value", scope, el)
        param = ns_join(ns or "", param or "")
        cmd = cmd or "load"
        if cmd not in ("load", "dump", "delete"):
            raise self._fail(scope, el, "error loading <rosparam> tag: command must be 'load', 'dump', or 'delete'")
        if file_ is not None:
            if cmd == "load" and not os.path.isfile(file_):
                raise self._fail(scope, el, "error loading <rosparam> tag: file does not exist [%s]%s"
                                 % (file_, _near_files(file_)))
            if cmd == "delete":
                raise self._fail(scope, el, "error loading <rosparam> tag: 'file' attribute is invalid with "
                                            "'delete' command.")
        full_param = ns_join(scope.ns, param) if param else scope.ns
        if full_param[:1] == "~":
            # (in a <node> too: roslaunch resolves a <rosparam>'s ~ against no node; the master resolves the name
            # it is given against its caller, roslaunch)
            self._warn(scope, el, "<rosparam param=\"%s\"> sets its parameters under the literal name [%s], which "
                                  "the master resolves against roslaunch's own name, as for roslaunch: [%s], not "
                                  "a node's" % (param, full_param, resolve_name(full_param, CALLER_ID)))
        if cmd == "dump":
            if not file_:  # (roslaunch runs `rosparam dump` with no file then, and its launch dies of a TypeError)
                self._warn(scope, el, "<rosparam command=\"dump\"> without a file= dumps nothing (roslaunch's launch "
                                      "fails on it)")
            self.rosparam_commands.append(("dump", full_param, file_))
            return
        if cmd == "delete":
            self.rosparam_commands.append(("delete", full_param, None))
            return
        if file_:
            self.yaml_files.setdefault(os.path.abspath(file_))
            try:
                text = _read_text(file_)
            except (OSError, UnicodeDecodeError) as e:
                raise self._fail(scope, el, "error loading <rosparam> tag: cannot read [%s]: %s"
                                 % (file_, getattr(e, "strerror", None) or e)) from None
        else:
            text = element_text(el)
        if subst_value:
            text = self._sub(text, scope, el) or ""
        self._ros_yaml = True
        data = self._yaml(text, scope, el, angles=True, what="<rosparam>", yaml_file=file_ or None)
        if data is None:
            data = {}
        if not param and not isinstance(data, dict):
            raise self._fail(scope, el, "error loading <rosparam> tag: 'param' attribute must be set for "
                                        "non-dictionary values")
        self._unroll(full_param, data, scope, el)

    def _unroll(self, key: str, value: Any, scope: Scope, el: Any) -> None:
        if not key:
            raise self._fail(scope, el, "no parameter name specified")
        if not isinstance(value, dict):
            if key == SEP:
                raise self._fail(scope, el, "Cannot load non-dictionary types into global namespace '/'")
            self._add_param(key, value, scope, el)
            return
        # ns_join(key, k) for each k, with the join worked out once (YAML files have thousands of keys)
        prefix = key if key[-1] == SEP else PRIV_NAME if key == PRIV_NAME else key + SEP
        add = self._add_param
        for k, v in value.items():
            if type(k) is not str and not isinstance(k, str):
                raise self._fail(scope, el, "error loading <rosparam> tag: parameter names must be strings, "
                                            "not %r (quote the key in the YAML)" % (k,))
            full = k if (k[:1] == SEP or k[:1] == PRIV_NAME) else prefix + k
            if isinstance(v, dict) or full == SEP:
                self._unroll(full, v, scope, el)
            else:
                add(full, v, scope, el)

    # ------------------------------------------------------------------ <node>, <test>
    # A <node> or <test> is read in roslaunch's order, so the same input meets the same first
    # error: its own attributes (the test ones or the extension ones), its namespace and params
    # scope, the run attributes, its children, then the launch-level ~params it picks up, the
    # remaining checks, and the record.
    def _node_tag(self, el: Any, scope: Scope, default_machine: Machine | None, is_test: bool) -> None:
        if is_test:
            name, test = self._test_attrs(el, scope)
            own_policy: dict[str, Any] = {}
        else:
            test = None
            own_policy = {}  # the node's own extension attributes
            if not ROSLAUNCH_NODE_ATTRS.issuperset(el.attrib):  # (the usual case: no extension either)
                self._check_attrs(el, scope, NODE_ATTRS)
                own_policy = self._policy(el, scope)
            name = self._reqd(el, "name", scope)
        if not is_legal_name(name):
            self._warn(scope, el, "illegal <%s> name '%s' (see http://ros.org/wiki/Names); this will likely "
                                  "cause problems with other ROS tools" % (el.tag, name))
        child = self._ns_clear_params(el, scope, "node", node_name=name)
        try:
            param_scope = child.node_child(name)
        except ScopeError as e:
            raise self._fail(scope, el, "Invalid <%s> tag: %s" % (el.tag, e)) from None
        param_scope.params = []
        run = self._run_attrs(el, scope, default_machine, is_test, own_policy)
        node_remaps, env_scope = self._node_children(el, scope, param_scope)
        self._node_params(scope, param_scope)
        self._check_node(el, scope, name, run, is_test)
        namespace = child.ns
        if "//" in namespace:
            namespace = _MULTISLASH.sub("/", namespace)
        remaps = scope.remap_args_with(node_remaps)
        env_args = tuple((env_scope or scope).env_args)
        pkg, node_type, machine, args, output, respawn, respawn_delay, required, cwd, launch_prefix = run
        if is_test:
            test_name, time_limit, retry = test  # type: ignore[misc]
            node = Node(pkg, node_type, name or "", namespace, args or "", remaps, env_args, respawn, respawn_delay,
                        required, "log", cwd, launch_prefix or None, machine or None, scope.filename or scope.source,
                        el.sourceline or 0, test_name, time_limit or TEST_TIME_LIMIT_DEFAULT, retry, None)
            self.tests.append(node)
            return
        node = Node(pkg, node_type, name or "", namespace, args or "", remaps, env_args, respawn, respawn_delay,
                    required, output, cwd, launch_prefix or None, machine or None, scope.filename or scope.source,
                    el.sourceline or 0, None, None, 0,
                    self._node_policy(scope.policy, own_policy, namespace, name or "", remaps))
        if name:
            full = ns_join(namespace, name)
            if full in self.node_names:
                raise self._fail(scope, el, "roslaunch file contains multiple nodes named [%s].\nPlease check all "
                                            "<node> 'name' attributes to make sure they are unique.\nAlso check "
                                            "that $(anon id) use different ids." % full)
            self.node_names.add(full)
        self.nodes.append(node)

    def _test_attrs(self, el: Any, scope: Scope) -> tuple[str, tuple[str, float | None, int]]:
        """A <test>'s name (its test-name when it has none) and (test-name, time limit, retries)."""
        a = self._attr
        self._check_attrs(el, scope, TEST_ATTRS)
        name = a(el, "name", scope)
        for bad in ("respawn", "respawn_delay", "output"):
            if bad in el.attrib:
                raise self._fail(scope, el, "Invalid <test> tag: <test> tags cannot have '%s' attribute" % bad)
        test_name = self._reqd(el, "test-name", scope)
        tl = a(el, "time-limit", scope)
        rt = a(el, "retry", scope)
        time_limit: float | None = None
        retry = 0
        if tl:
            try:
                time_limit = float(tl)
            except ValueError:
                raise self._fail(scope, el, "Invalid <test> tag: 'time-limit' must be a number: [%s]" % tl) from None
            if time_limit <= 0.0:
                raise self._fail(scope, el, "Invalid <test> tag: 'time-limit' must be a positive number")
        if rt:
            try:
                retry = int(rt)
            except ValueError:
                raise self._fail(scope, el, "Invalid <test> tag: 'retry' must be a number: [%s]" % rt) from None
        return name or test_name, (test_name, time_limit, retry)

    def _run_attrs(self, el: Any, scope: Scope, default_machine: Machine | None, is_test: bool,
                   own_policy: dict[str, Any]) -> tuple:
        """(pkg, type, machine, args, output, respawn, respawn_delay, required, cwd, launch-prefix): the
        attributes of how the node runs, substituted and typed (output and cwd are checked later)."""
        pkg = self._reqd(el, "pkg", scope)
        node_type = self._reqd(el, "type", scope)
        get = el.attrib.get
        machine, args, output, respawn_s, respawn_delay_s, cwd, launch_prefix, required_s = [
            v if (not v or "$" not in v) else self._sub(v, scope, el)
            for v in (get("machine"), get("args"), get("output"), get("respawn"), get("respawn_delay"),
                      get("cwd"), get("launch-prefix"), get("required"))]
        if cwd == "ros_home":
            cwd = "ROS_HOME"
        if not machine and default_machine is not None:
            machine = default_machine.name
        if respawn_delay_s is not None and respawn_s is None and not is_test:
            self._warn(scope, el, "respawn_delay has no effect without respawn=\"true\"")
        required = False if required_s is None else self._bool(required_s, False, "required", scope, el)
        respawn = False if respawn_s is None else self._bool(respawn_s, False, "respawn", scope, el)
        if own_policy and not respawn:
            for attr in sorted(RESPAWN_ONLY.intersection(el.attrib.keys())):
                self._warn(scope, el, "%s has no effect without respawn=\"true\"" % attr)
        if respawn_delay_s is None:
            respawn_delay = 0.0
        elif not respawn_delay_s:
            raise self._fail(scope, el, "Invalid <%s> tag: value for respawn_delay must be non-empty" % el.tag)
        else:
            try:
                respawn_delay = float(respawn_delay_s)
            except ValueError:
                raise self._fail(scope, el, "Invalid <%s> tag: invalid float value for respawn_delay: %s"
                                 % (el.tag, respawn_delay_s)) from None
        return pkg, node_type, machine, args, output, respawn, respawn_delay, required, cwd, launch_prefix

    def _node_children(self, el: Any, scope: Scope, param_scope: Scope) -> tuple[list[tuple[str, str]], Scope | None]:
        """A node's <remap>, <param>, <rosparam> and <env> children: its own remaps (on top of the scope's)
        and the scope holding its env (None: the enclosing scope's); its params go to `param_scope`."""
        node_remaps: list[tuple[str, str]] = []
        env_scope: Scope | None = None
        for c in el:
            ctag = c.tag.lower()  # roslaunch matches a node's child tags case-insensitively
            cget = c.attrib.get
            plain = cget("if") is None and cget("unless") is None  # no if/unless to evaluate
            if ctag == "remap":
                if plain or self._if_unless(c, scope):
                    src, dst = self._remap_tag(c, scope)
                    try:
                        add_remap_to(node_remaps, src, dst)
                    except ScopeError as e:
                        raise self._fail(scope, c, "Invalid <remap> tag: %s" % e) from None
            elif ctag == "param":
                if plain or self._if_unless(c, param_scope):
                    self._param_tag(c, param_scope, force_local=True)
            elif ctag == "rosparam":
                if plain or self._if_unless(c, param_scope):
                    self._rosparam_tag(c, param_scope)
            elif ctag == "env":
                if env_scope is None:
                    env_scope = scope.node_child("")
                    env_scope.env_args = list(scope.env_args)
                if plain or self._if_unless(c, env_scope):
                    self._env_tag(c, env_scope)
            else:
                self._warn(scope, c, "unrecognized <%s> child tag of <%s> (ignored)" % (ctag, el.tag))
        return node_remaps, env_scope

    def _node_params(self, scope: Scope, param_scope: Scope) -> None:
        """The node's private params: the launch-level ~params declared earlier in its scope, then its own."""
        node_params = param_scope.params
        if scope.params:
            for key, value, pfile, pline in scope.params:
                self._used_private.add((key, pfile, pline))
            node_params = scope.params + node_params
        ns = param_scope.ns
        params = self.params
        key_lengths = self._key_lengths
        for key, value, pfile, pline in node_params:
            if key[:1] == "~":
                key = key[1:]
            full = ns + key
            if "//" in full or (full[-1:] == SEP and len(full) > 1):  # (canonical(), inline)
                full = canonical(full)
            params[full] = new_param(full, value, pfile, pline)
            key_lengths.add(len(full))
        self._clean_ns = None

    def _check_node(self, el: Any, scope: Scope, name: str, run: tuple, is_test: bool) -> None:
        """roslaunch's checks of a node once its children are read (the same messages, in the same order)."""
        pkg, node_type, _machine, _args, output, respawn, _delay, required, cwd, _prefix = run
        if respawn and required:
            raise self._fail(scope, el, "Invalid <%s> tag: respawn and required cannot both be set to true" % el.tag)
        if name and SEP in name:
            raise self._fail(scope, el, "Invalid <%s> tag: node name cannot contain a namespace" % el.tag)
        if not pkg.strip():
            raise self._fail(scope, el, "Invalid <%s> tag: package must be non-empty" % el.tag)
        if not node_type.strip():
            raise self._fail(scope, el, "Invalid <%s> tag: type must be non-empty" % el.tag)
        if not is_test and output not in ("log", "screen", None):
            raise self._fail(scope, el, "Invalid <node> tag: output must be one of 'log', 'screen' (got '%s')" % output)
        if cwd not in ("ROS_HOME", "node", None):
            raise self._fail(scope, el, "Invalid <%s> tag: cwd must be one of 'ROS_HOME', 'node' (got '%s')"
                             % (el.tag, cwd))

    @staticmethod
    def _node_policy(defaults: dict[str, Any] | None, own: dict[str, Any], namespace: str,
                     name: str, remaps: tuple[tuple[str, str], ...] = ()) -> NodePolicy | None:
        """The node's NodePolicy: its scope's defaults under its own attributes; None if neither sets any."""
        if not defaults and not own:
            return None
        fields = {**defaults, **own} if defaults else own
        if "wait_for" in fields:
            fields = dict(fields, wait_for=resolve_wait_names(fields["wait_for"], namespace,
                                                              ns_join(namespace, name)))
        if fields.get("bind_to"):
            # start after it (a wait_for condition), stopped before it (the supervisor's shutdown order)
            (bound,) = resolve_wait_names((("node", fields["bind_to"]),), namespace, ns_join(namespace, name))
            waits = tuple(fields.get("wait_for", ()))
            fields = dict(fields, bind_to=bound[1], wait_for=waits if bound in waits else waits + (bound,))
        if "watch_topics" in fields:
            fields = dict(fields, watch_topics=resolve_watch_topics(fields["watch_topics"], namespace,
                                                                    ns_join(namespace, name), remaps))
        return NodePolicy(**fields)

    # ------------------------------------------------------------------ <machine>
    def _machine_tag(self, el: Any, scope: Scope) -> tuple[Machine, bool]:
        a = self._attr
        for old in ("ros-root", "ros-package-path", "ros-ip", "ros-hostname"):
            if a(el, old, scope):
                raise self._fail(scope, el, "<machine>: ros-* attributes are not supported since ROS Fuerte.\n"
                                            "Please use env-loader instead")
        self._check_attrs(el, scope, MACHINE_ATTRS)
        name = self._reqd(el, "name", scope)
        address = self._reqd(el, "address", scope)
        env_loader, ssh_port_s, user, password, default, timeout_s = (
            a(el, x, scope) for x in ("env-loader", "ssh-port", "user", "password", "default", "timeout"))
        try:
            ssh_port = int(ssh_port_s or "22")
        except ValueError:
            raise self._fail(scope, el, "Invalid <machine> tag: ssh-port must be an integer: [%s]" % ssh_port_s) from None
        default = (default or "false").lower()
        if default not in ("true", "false", "never"):
            raise self._fail(scope, el, "Invalid value for 'default' attribute of <machine>: %s "
                                        "(use true, false or never)" % default)
        for c in el:
            if c.tag == "env":
                raise self._fail(scope, c, "<machine>: <env> tag is not supported since ROS Fuerte.\n"
                                           "Please use env-loader instead")
            self._warn(scope, c, "unrecognized <%s> tag in <machine> tag (ignored)" % c.tag)
        if timeout_s:
            try:
                timeout = float(timeout_s)
            except ValueError:
                raise self._fail(scope, el, "Invalid <machine> tag: 'timeout' must be a number: [%s]" % timeout_s) from None
        elif timeout_s == "":
            raise self._fail(scope, el, "Invalid <machine> tag: 'timeout' cannot be empty")
        else:
            timeout = MACHINE_TIMEOUT_DEFAULT
        if timeout <= 0.0:
            raise self._fail(scope, el, "Invalid <machine> tag: 'timeout' must be a positive number: [%s]" % timeout_s)
        if not env_loader:
            env_loader = "/opt/ros/%s/env.sh" % self.environ.get("ROS_DISTRO", "noetic")
        m = Machine(name=name, address=address, env_loader=env_loader, ssh_port=ssh_port, user=user or None,
                    password=password, assignable=default != "never", timeout=timeout,
                    filename=scope.source, line=el.sourceline or 0)
        old_m = self.machines.get(name)
        if old_m is not None:
            if _machine_key(old_m) != _machine_key(m):
                raise self._fail(scope, el, "Machine [%s] already added and does not match duplicate entry "
                                            "(first defined at %s:%d)" % (name, old_m.filename, old_m.line))
        else:
            self.machines[name] = m
        return m, default == "true"

    # ------------------------------------------------------------------ <include>
    def _include_tag(self, el: Any, scope: Scope, default_machine: Machine | None) -> Machine | None:
        self._check_attrs(el, scope, INCLUDE_ATTRS)
        inc_file = self._reqd(el, "file", scope)
        pass_all = False
        if "pass_all_args" in el.attrib:
            pass_all = self._bool(self._attr(el, "pass_all_args", scope), False, "pass_all_args", scope, el)
        child = self._ns_clear_params(el, scope, "include", include_file=inc_file)
        self._scope_policy(el, scope, child)
        if pass_all:
            for k, v in scope.args.items():
                child.add_arg(k, value=v)
            child.pass_all_args = True
        # the include's own <arg>/<env> children are evaluated in the including file
        child.filename = scope.filename
        for c in el:
            ctag = c.tag.lower()
            if ctag == "env":
                if self._if_unless(c, child):
                    self._env_tag(c, child)
            elif ctag == "arg":
                self._arg_tag(c, child)
            else:
                self._warn(scope, c, "unrecognized <%s> tag in <include> tag (ignored: roslaunch does not "
                                     "support it there)" % c.tag)
        child.filename = inc_file
        try:
            child.start_include()
        except ScopeError as e:
            raise self._fail(scope, el, "%s for include of [%s]" % (e, inc_file)) from None
        chain = ((scope.source, el.sourceline or 0),) + scope.include_chain
        if len(chain) > MAX_INCLUDE_DEPTH:
            raise self._fail(scope, el, "includes are nested more than %d deep" % MAX_INCLUDE_DEPTH)
        # (whether it exists first: os.path.realpath is quadratic in the number of a path's parts)
        if not os.path.exists(inc_file):
            raise self._fail(scope, el, "included file [%s] does not exist%s" % (inc_file, _near_files(inc_file)))
        real = self._realpath(inc_file)
        if any(self._realpath(f) == real for f, _ in chain):
            raise self._fail(scope, el, "include cycle: [%s] includes itself" % inc_file)
        child.source = inc_file
        child.include_chain = chain
        doc = read_launch(inc_file, include_chain=chain)
        launch = doc.launch
        self.files.append(inc_file)
        self._launch_tag(launch, child)
        default_machine = self._recurse(launch, child, default_machine)
        if not pass_all:
            unused = child.unused_include_args()
            if unused:
                raise self._fail(scope, el, "unused args [%s] for include of [%s]" % (", ".join(unused), inc_file))
        return default_machine


def _near_files(path: str) -> str:
    """" (did you mean NAME?)" for a missing file whose folder holds one of a close name, else ""."""
    hint = near_file(path)
    return " (%s)" % hint if hint else ""


# tag -> handler, for the children of <launch>, <group> and an included file's <launch>
_TAG_HANDLERS: dict[str, Callable[[XmlLoader, Any, Scope, Machine | None], Machine | None]] = {
    "node": XmlLoader._node_element, "test": XmlLoader._test_element, "param": XmlLoader._param_element,
    "rosparam": XmlLoader._rosparam_element, "env": XmlLoader._env_element, "remap": XmlLoader._remap_element,
    "group": XmlLoader._group_element, "include": XmlLoader._include_tag, "machine": XmlLoader._machine_element,
}
# (an attribute, so that a subclass can wrap them: `launcher check` goes on past an element's error)
XmlLoader.tag_handlers = _TAG_HANDLERS


def _read_text(path: str) -> str:
    """A UTF-8 text file as open(path, "r", encoding="utf-8").read() gives it (universal newlines),
    without a text-mode file's incremental decoder (a YAML file per <rosparam file=...>)."""
    with open(path, "rb") as f:
        text = f.read().decode("utf-8")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


_LONG_RUN = re.compile(r"[^\s\[\]'\"]{%d,}" % (SHOWN_CHARS + 1))


def _shortened(msg: str) -> str:
    """A message that quotes long texts of the user's, shortened: each long run of them by
    `errors.shorten`, then, if still long (a long text of short words), its middle left out
    (a 5 MB value makes no readable error; the start and the end say which and what is wrong)."""
    if len(msg) <= 4 * SHOWN_CHARS:
        return msg
    msg = _LONG_RUN.sub(lambda m: shorten(m.group(0)), msg)
    if len(msg) <= 12 * SHOWN_CHARS:
        return msg
    return "%s[... %d characters ...]%s" % (msg[:2 * SHOWN_CHARS], len(msg) - 3 * SHOWN_CHARS, msg[-SHOWN_CHARS:])


def _machine_key(m: Machine) -> tuple:
    return (m.name, m.address, m.env_loader, m.ssh_port, m.user, m.password, m.assignable, m.timeout)
