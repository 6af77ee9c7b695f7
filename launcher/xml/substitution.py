"""Substitution args in launch attributes: `$(arg) $(env) $(optenv) $(anon) $(dirname) $(find) $(eval)`.

The algorithm is roslaunch's (substitution_args.py), because users depend on
its corner cases: `$(...)` commands are collected by the same little state
machine, the value of each replaces every copy of its text, `$(find)` runs in a
second pass over the already substituted string (so an arg whose value
contains `$(find pkg)` is expanded too), and `$(eval ...)` must be the whole
attribute. `$(eval)` is not Python's eval(): `xml/sandbox.py` walks the expression's
syntax tree over roslaunch's names, with an allowlist and a bound on the work.

roslaunch rescans the whole string once per `$(...)` (a `replace` each), so its time
grows with the square of a long attribute. Here both passes are linear in the text and
in what they insert: one str.format() wherever a single pass provably gives what
roslaunch's replacements give (nearly always), and `_Pieces` (the string cut at its
'$'s, so that a replacement touches only the pieces around each copy) where a value
brings a '$' and may make new `$(...)` texts. Hostile input meets documented limits,
each a SubstitutionError that the loader reports with file and line:

- MAX_VALUE_CHARS: the length of one substituted value (64 Mi; a 5 MB URDF is a large real one);
- MAX_LOAD_CHARS: the text substitutions make in one load, in values of more than 4 kB
  (512 Mi; args that double each other; what shorter ones make is bounded by the files);
- MAX_REPLACEMENTS: `$(...)` copies replaced in one attribute beyond those of its own text
  (values that keep making each other's `$(...)` texts);
- `$(find)`s whose path (the text up to a space) runs into the next `$(...)` can only be
  done as roslaunch does them, rescanning the string per `$(find)`: FIND_RESCANS rescans of
  it, plus FIND_RESCAN_CHARS characters, then an error that says to put a space after each.
"""

from __future__ import annotations

import os
import re

from launcher.model.errors import shorten
from launcher.model.names import AnonNames, anonymous_name
from launcher.params.values import auto_value

TYPE_CHECKING = False  # (typing.TYPE_CHECKING without importing typing: ~3 ms a start; the annotations are text)
if TYPE_CHECKING:
    from typing import Any, Callable, Mapping

VALID_COMMANDS = ("find", "env", "optenv", "dirname", "anon", "arg")

MAX_VALUE_CHARS = 64 * 1024 * 1024
MAX_LOAD_CHARS = 512 * 1024 * 1024
MAX_REPLACEMENTS = 1 << 20
FIND_RESCANS = 16
FIND_RESCAN_CHARS = 1 << 16


class SubstitutionError(Exception):
    """A `$(...)` that cannot be evaluated; the loader adds file and line."""


class ArgNotSet(SubstitutionError):
    """`$(arg name)` for an arg that has no value; `.name` is the arg."""

    def __init__(self, name: str):
        self.name = name
        super().__init__(name)


class LoadBudget:
    """The characters substitutions may still make in one load (MAX_LOAD_CHARS), shared by all its scopes;
    and the anonymous names a run's loads share (`AnonNames`), if any."""

    __slots__ = ("left", "anon_names")

    def __init__(self, chars: int = MAX_LOAD_CHARS, anon_names: AnonNames | None = None):
        self.left = chars
        self.anon_names = anon_names

    def spend(self, chars: int) -> None:
        self.left -= chars
        if self.left < 0:
            raise SubstitutionError("substitution args have made more than %d characters of text in this launch, "
                                    "the limit (do args copy each other over and over?)" % MAX_LOAD_CHARS)


class SubstitutionScope:
    """What a substitution can see: the scope's args and anon names, the file, the environment, packages."""

    __slots__ = ("args", "anon", "filename", "environ", "find_package", "find_resource", "used_args", "budget")

    def __init__(self, args: Mapping[str, str], anon: dict[str, str], filename: str | None,
                 environ: Mapping[str, str], find_package: Callable[[str], str],
                 find_resource: Callable[[str, str], str], used_args: set[str] | None = None,
                 budget: LoadBudget | None = None):
        self.args = args
        self.anon = anon
        self.filename = filename
        self.environ = environ
        self.find_package = find_package
        self.find_resource = find_resource
        # the names `$(arg)` (and `arg()` in `$(eval)`) have read: one set shared by a whole load,
        # so that the loader can tell a command-line arg nothing reads (a typo, usually)
        self.used_args = set() if used_args is None else used_args
        self.budget = LoadBudget() if budget is None else budget


# A `$(...)` text: what roslaunch's state machine (_collect_args) collects, when the text has no
# misplaced '$' or '(' (a `$(` whose body meets one before its ')': the machine's two errors).
_COMMAND = re.compile(r"\$\(([^$()]+)\)")
_MISPLACED = re.compile(r"\$\([^$()]*([$(])")
_AFTER_DOLLAR = r"(?<=\$)\$\(([^$()]+)\)"  # (rarely needed: compiled at first use, by re's cache)
_PATH = re.compile(r"[^ ]*")  # what a $(find pkg) takes as its path: the text up to a space


def _check_commands(text: str) -> None:
    bad = _MISPLACED.search(text)
    if bad is not None:
        if bad.group(1) == "$":
            raise SubstitutionError("Dollar signs '$' cannot be inside of substitution args [%s]" % shorten(text))
        raise SubstitutionError("Invalid left parenthesis '(' in substitution args [%s]" % shorten(text))


def collect_commands(text: str) -> list[str]:
    """The bodies of the `$(...)` in `text`, in order (roslaunch's `_collect_args` state machine)."""
    _check_commands(text)
    return _COMMAND.findall(text)


def _words(body: str) -> list[str]:
    words = body.split(" ")  # (roslaunch splits at spaces only: a tab is part of a word)
    return [w for w in words if w] if "" in words else words


def resolve(text: str | None, scope: SubstitutionScope) -> str | None:
    """`text` with every substitution arg replaced; None stays None."""
    if not text or "$" not in text:
        return text
    if text.startswith("$(eval ") and text.endswith(")"):
        return _made(evaluate(text[7:-1], scope), scope)
    resolved = _first_pass_resolve(text, scope)
    if "$" in resolved:
        resolved = _find_pass_resolve(resolved, scope)
    return resolved


def _unknown(body: str) -> SubstitutionError:
    return SubstitutionError("Unknown substitution command [%s]. Valid commands are %s"
                             % (shorten(body), list(VALID_COMMANDS)))


def _too_long(chars: int) -> SubstitutionError:
    return SubstitutionError("substitution args make a value of %d characters, more than the limit of %d"
                             % (chars, MAX_VALUE_CHARS))


# (a short value is not counted: what a load makes of them is bounded by the length of its files)
_CHARGED_FROM = 4096


def _made(text: str, scope: SubstitutionScope) -> str:
    """A string a substitution has built: counted against the load's budget."""
    if len(text) > _CHARGED_FROM:
        scope.budget.spend(len(text))
    return text


def _braces(text: str) -> str:
    return text.replace("{", "{{").replace("}", "}}") if ("{" in text or "}" in text) else text


# A launch tree repeats the same attribute texts many times (the same include's nodes and
# params, once per include): what a text asks for is worked out once per distinct text. The
# plans depend on the text alone; the values come from the scope at every use. (A long text is
# planned each time: it is rarely repeated, and its plan is as long as it is.)
_PLAN_MAX = 16384
_PLAN_TEXT_MAX = 64 * 1024
_FIRST_PLANS: dict[str, _FirstPlan] = {}
_FIND_PLANS: dict[str, _FindPlan] = {}


def _planned(plans: dict, make: Callable[[str], Any], text: str) -> Any:
    plan = plans.get(text)
    if plan is None:
        plan = make(text)  # (raises for a malformed text: nothing kept)
        if len(plans) < _PLAN_MAX and len(text) <= _PLAN_TEXT_MAX:
            plans[text] = plan
    return plan


class _FirstPlan:
    """What the first pass does to one text.

    roslaunch replaces, for each `$(...)` in order, every copy of its text in the string as it
    stands. `commands` are the distinct non-find commands (body, command, args) in order, up to an
    unknown one (command None), each evaluated once; `order` is every non-find body in order, the
    replacements roslaunch makes. `template` is a str.format template with a field for each copy
    of each command (a `$(find)` stays as it is, for the second pass), `counts` the copies of each
    (`most` the largest) and `literal` the length of the rest: one format() call, in C, does the replacing, when no
    replacement can make a new `$(...)` text (see _one_pass_is_roslaunchs); `after_dollar` are
    the commands with a copy right after a '$', `whole` says the text is one `$(...)`.
    """

    __slots__ = ("commands", "order", "nothing", "template", "counts", "most", "literal", "after_dollar", "whole")

    def __init__(self, text: str):
        _check_commands(text)
        pieces = _COMMAND.split(text)  # literal, body, literal, ..., literal
        bodies = pieces[1::2]
        # each distinct body looked at once (a long text repeats a few, many times), in order
        commands: list[tuple[str, str | None, tuple[str, ...]]] = []
        index: dict[str, int] = {}  # non-find body -> its value's position
        finds = False
        cut = len(bodies)
        for body in dict.fromkeys(bodies):
            words = _words(body)
            if not words or words[0] not in VALID_COMMANDS:
                commands.append((body, None, ()))
                cut = bodies.index(body)  # (roslaunch stops at the first unknown command)
                break
            if words[0] == "find":
                finds = True
            else:
                index[body] = len(commands)
                commands.append((body, words[0], tuple(words[1:])))
        if cut < len(bodies):
            bodies = bodies[:cut]
        self.commands = tuple(commands)
        self.order = tuple(b for b in bodies if b in index) if finds else tuple(bodies)
        self.nothing = not commands  # only $(find)s, for the second pass
        self.whole = len(commands) == 1 and len(self.order) == 1 and text == "$(%s)" % self.order[0]
        self.template: str | None = None
        self.counts = [0] * len(commands)
        self.most = 0  # the most copies of one command
        self.literal = len(text)
        self.after_dollar: tuple[int, ...] = ()
        if not commands or commands[-1][1] is None:
            return  # (an unknown command: resolving raises)
        counts = self.counts
        for body in self.order:
            counts[index[body]] += 1
            self.literal -= len(body) + 3
        self.most = max(counts)
        if "$$(" in text:
            self.after_dollar = tuple({index[b] for b in re.findall(_AFTER_DOLLAR, text) if b in index})
        braces = "{" in text or "}" in text
        if braces:
            pieces[0::2] = [p.replace("{", "{{").replace("}", "}}") for p in pieces[0::2]]
        fields = {b: "{%d}" % k for b, k in index.items()}
        # (a $(find) stays as it is, for the second pass)
        pieces[1::2] = [fields.get(b) or _braces("$(%s)" % b) for b in pieces[1::2]] if finds or braces else \
            [fields[b] for b in pieces[1::2]]
        self.template = "".join(pieces)


def _one_pass_is_roslaunchs(values: list[str], dollar: bool, after_dollar: tuple[int, ...]) -> bool:
    """Whether replacing every `$(...)` of the text at once gives what roslaunch's replacements one
    after another give (`dollar`: some value holds a '$').

    A `$(...)` text holds one '$', its first character. When no value holds a '$', every '$' of
    the string is one of the text's own, and a new `$(...)` text could only start at a '$' whose
    following characters a replacement changed: a '$' right before a copy (whose value then
    follows it: a problem if it is empty or starts with '('), or a `$(` with a copy inside its
    body, which the text's check has refused. So no replacement makes a new `$(...)` text, and
    each replaces exactly the text's own copies of its `$(...)`.
    """
    if dollar:
        return False
    for k in after_dollar:
        v = values[k]
        if not v or v[0] == "(":
            return False
    return True


def _first_pass_resolve(text: str, scope: SubstitutionScope) -> str:
    plan = _FIRST_PLANS.get(text) or _planned(_FIRST_PLANS, _FirstPlan, text)
    if plan.nothing:
        return text
    values = []
    dollar = False
    for body, cmd, args in plan.commands:
        if cmd is None:
            raise _unknown(body)
        value = _first_pass(cmd, body, args, scope)
        if "$" in value:
            dollar = True
        values.append(value)
    if plan.whole:
        return values[0]  # (the value itself: roslaunch's one replace makes nothing else of it)
    if not dollar and (not plan.after_dollar or _one_pass_is_roslaunchs(values, dollar, plan.after_dollar)):
        # copies of a value multiply it: measured before they are made (one copy each is no
        # longer than what the values and the text already are, and is measured after)
        if plan.most > 1 and plan.literal + plan.most * sum(map(len, values)) > MAX_VALUE_CHARS:
            chars = plan.literal + sum(count * len(v) for count, v in zip(plan.counts, values))
            if chars > MAX_VALUE_CHARS:
                raise _too_long(chars)
        out = plan.template.format(*values)  # type: ignore[union-attr]
    else:
        out = _Pieces(text).replace_in_order(plan.order, {c[0]: v for c, v in zip(plan.commands, values)})
    if len(out) > _CHARGED_FROM:
        if len(out) > MAX_VALUE_CHARS:
            raise _too_long(len(out))
        scope.budget.spend(len(out))
    return out


# ---------------------------------------------------------------------------
# roslaunch's one-by-one replacements, in linear time

_PAREN = re.compile(r"[()]")
_FRESH, _OPEN, _NONE, _KEY = range(4)  # what a piece is known to start with


class _Piece:
    """The text between two '$'s of the string (or before the first), as a chain of segments.

    A `$(body)` text holds no '$' but its first character, so each copy of one is the start of
    the piece after its '$'. A piece only ever grows at its end (a replacement appends to the
    piece before the copy it replaces), so what it starts with is found once: `state` _FRESH
    (empty so far), _OPEN (a '(' and body characters so far), _NONE (no `$(...)` text), _KEY
    (`$(key)`, the rest starting at `seg`/`pos`). A segment is [text, start, end, next segment];
    `seg`/`pos` is where scanning goes on (a _FRESH or _OPEN piece), `body` where the key starts.
    """

    __slots__ = ("head", "tail", "state", "seg", "pos", "body_seg", "body_pos", "prev", "next")

    def __init__(self, text: str, state: int = _FRESH):
        seg = [text, 0, len(text), None] if text else None
        self.head = self.tail = self.seg = seg
        self.pos = 0
        self.state = state
        self.body_seg: list | None = None
        self.body_pos = 0
        self.prev: _Piece | None = None
        self.next: _Piece | None = None

    def append(self, head: list, tail: list) -> None:
        """Add a chain of segments at the end."""
        if self.tail is None:
            self.head = self.seg = head
            self.pos = head[1]
        else:
            self.tail[3] = head
        self.tail = tail

    def scan(self) -> str | None:
        """Read on from where the last scan stopped; the key, if the piece has just been found to have one."""
        seg, pos, state = self.seg, self.pos, self.state
        while seg is not None:
            text, _start, end, following = seg
            if pos < end:
                if state == _FRESH:
                    if text[pos] != "(":
                        self.state = _NONE
                        return None
                    state = _OPEN
                    pos += 1
                    self.body_seg, self.body_pos = seg, pos
                    continue
                m = _PAREN.search(text, pos, end)
                if m is not None:
                    j = m.start()
                    key = self._text_to(seg, j) if text[j] == ")" else ""
                    if not key:  # `$((` or `$()`
                        self.state = _NONE
                        return None
                    self.state, self.seg, self.pos = _KEY, seg, j + 1
                    return key
                pos = end
            if following is None:
                break
            seg, pos = following, following[1]
        self.seg, self.pos, self.state = seg, pos, state
        return None

    def _text_to(self, seg: list, pos: int) -> str:
        """The text from the key's start up to (seg, pos)."""
        s = self.body_seg
        if s is seg:
            return seg[0][self.body_pos:pos]
        parts = [s[0][self.body_pos:s[2]]]  # type: ignore[index]
        s = s[3]  # type: ignore[index]
        while s is not seg:
            parts.append(s[0][s[1]:s[2]])
            s = s[3]
        parts.append(seg[0][seg[1]:pos])
        return "".join(parts)

    def rest(self) -> tuple[list | None, list | None]:
        """The chain of segments after a _KEY piece's key, as (head, tail); (None, None) if empty."""
        seg, pos = self.seg, self.pos
        assert seg is not None
        if pos < seg[2]:
            first = [seg[0], pos, seg[2], seg[3]]
            return first, (first if self.tail is seg else self.tail)
        if self.tail is seg:
            return None, None
        return seg[3], self.tail


class _Pieces:
    """A string cut at its '$'s, with the pieces that start with a `$(...)` text found by its body."""

    def __init__(self, text: str):
        parts = text.split("$")
        self.first = _Piece(parts[0], _NONE)  # (no '$' before it)
        self.size = len(text)
        self.copies: dict[str, list[_Piece]] = {}
        self.replacements_left = MAX_REPLACEMENTS + len(parts)
        prev = self.first
        for part in parts[1:]:
            piece = _Piece(part)
            piece.prev = prev
            prev.next = prev = piece
            self._found(piece)

    def _found(self, piece: _Piece) -> None:
        key = piece.scan()
        if key is not None:
            copies = self.copies.get(key)
            if copies is None:
                self.copies[key] = [piece]
            else:
                copies.append(piece)

    def replace_in_order(self, order: tuple[str, ...], value_of: dict[str, str]) -> str:
        """`s = s.replace("$(%s)" % body, value_of[body])` for each body in `order`, then the string."""
        copies = self.copies
        for body in order:
            found = copies.pop(body, None)
            if found:
                self._replace(found, len(body) + 3, value_of[body])
        return self.text()

    def _replace(self, found: list[_Piece], cut: int, value: str) -> None:
        """Every piece of `found` (copies of one `$(...)` text, `cut` characters with its '$') replaced
        by `value`; the pieces that changed are scanned once all are done, as str.replace does not
        look again at what it has made."""
        self.replacements_left -= len(found)
        if self.replacements_left < 0:
            raise SubstitutionError("substitution args would replace more than %d `$(...)` texts in this "
                                    "attribute (values that make each other's `$(...)` texts?)" % MAX_REPLACEMENTS)
        self.size += (len(value) - cut) * len(found)
        if self.size > MAX_VALUE_CHARS:
            raise _too_long(self.size)
        parts = value.split("$")
        first, others = parts[0], parts[1:]
        changed: list[_Piece] = []
        for piece in found:
            before = piece.prev
            assert before is not None
            rest_head, rest_tail = piece.rest()
            if first:
                seg = [first, 0, len(first), None]
                before.append(seg, seg)
            changed.append(before)
            last = before
            for text in others:
                new = _Piece(text)
                new.prev = last
                last.next = new
                last = new
                changed.append(new)
            if rest_head is not None:
                last.append(rest_head, rest_tail)  # type: ignore[arg-type]
            last.next = piece.next
            if piece.next is not None:
                piece.next.prev = last
        for piece in changed:
            if piece.state < _NONE:  # (_FRESH or _OPEN)
                self._found(piece)

    def text(self) -> str:
        out = []
        piece: _Piece | None = self.first
        while piece is not None:
            if piece is not self.first:
                out.append("$")
            seg = piece.head
            while seg is not None:
                text, start, end, seg = seg
                out.append(text if (start == 0 and end == len(text)) else text[start:end])
            piece = piece.next
        return "".join(out)


# ---------------------------------------------------------------------------
# the second pass: $(find)

class _FindPlan:
    """What the second pass does to one first-pass result.

    roslaunch replaces, for each `$(find)` in order, the first copy of its text in the string as
    it stands together with the path that follows it up to a space. `steps` are (body, args) of
    the finds in order, `unknown` the body of an unknown command that ends them (else None). When
    no path holds a '$', the k-th step always meets the k-th find (as in _one_pass_is_roslaunchs,
    given values without a '$'): `paths` are the paths, `after_dollar` which finds follow a '$',
    and `template` has a field for each find with its path, so that one format() does the steps.
    """

    __slots__ = ("steps", "unknown", "paths", "after_dollar", "template", "literal")

    def __init__(self, resolved: str):
        _check_commands(resolved)
        steps: list[tuple[str, tuple[str, ...]]] = []
        self.unknown: str | None = None
        paths: list[str] = []
        after_dollar: list[bool] = []
        pieces: list[str] = []
        pos = 0
        one_pass = True
        for m in _COMMAND.finditer(resolved):
            words = _words(m.group(1))
            if not words or words[0] not in VALID_COMMANDS:
                self.unknown = m.group(1)
                break
            if words[0] != "find":
                continue
            steps.append((m.group(1), tuple(words[1:])))
            if not one_pass:
                continue
            end = m.end()
            stop = _PATH.match(resolved, end).end()  # (paths do not overlap: each is read once)
            path = resolved[end:stop]
            if "$" in path:
                one_pass = False  # (it runs into another `$(...)` text: roslaunch's steps)
                continue
            pieces.append(_braces(resolved[pos:m.start()]))
            pieces.append("{%d}" % len(paths))
            paths.append(path)
            after_dollar.append(resolved[m.start() - 1:m.start()] == "$")
            pos = stop
        self.steps = tuple(steps)
        self.paths = tuple(paths)
        self.after_dollar = tuple(after_dollar)
        self.template: str | None = None
        self.literal = 0
        if one_pass and self.unknown is None:
            pieces.append(_braces(resolved[pos:]))
            self.template = "".join(pieces)
            self.literal = len(resolved) - sum(map(len, paths)) - sum(len(b) + 3 for b, _ in steps)


def _find_pass_resolve(resolved: str, scope: SubstitutionScope) -> str:
    plan = _FIND_PLANS.get(resolved) or _planned(_FIND_PLANS, _FindPlan, resolved)
    if plan.template is not None:
        values = []
        chars = plan.literal
        one_pass = True
        for (body, args), path, after_dollar in zip(plan.steps, plan.paths, plan.after_dollar):
            value = _find_value(body, args, path, scope)
            if "$" in value or (after_dollar and (not value or value[0] == "(")):
                one_pass = False
            chars += len(value)
            values.append(value)
        if one_pass:
            if chars > MAX_VALUE_CHARS:
                raise _too_long(chars)
            out = plan.template.format(*values)
            if len(out) > _CHARGED_FROM:
                scope.budget.spend(len(out))
            return out
    # roslaunch's steps, one by one: a path runs into another `$(...)` text, or a value brings a '$'
    work_left = FIND_RESCAN_CHARS + FIND_RESCANS * len(resolved)
    for body, args in plan.steps:
        work_left -= len(resolved)
        if work_left < 0:
            raise SubstitutionError(
                "the $(find)s of this attribute (%d characters) would take more than %d rescans of it, the "
                "limit: the path after a $(find pkg) runs up to the next space, here into the next $(...); "
                "put a space after each path" % (len(resolved), FIND_RESCANS))
        resolved = _find(resolved, body, args, scope)
        if len(resolved) > MAX_VALUE_CHARS:
            raise _too_long(len(resolved))
    if plan.unknown is not None:
        raise _unknown(plan.unknown)
    return _made(resolved, scope)


def _first_pass(cmd: str, body: str, args: tuple[str, ...], scope: SubstitutionScope) -> str:
    if cmd == "arg":
        if not args:
            raise SubstitutionError("$(arg var) must specify a variable name [%s]" % shorten(body))
        if len(args) > 1:
            raise SubstitutionError("$(arg var) may only specify one arg [%s]" % shorten(body))
        return _arg(args[0], scope)
    if cmd == "env":
        if len(args) != 1:
            raise SubstitutionError("$(env var) command only accepts one argument [%s]" % shorten(body))
        return _env(args[0], scope)
    if cmd == "optenv":
        if not args:
            raise SubstitutionError("$(optenv var) must specify an environment variable [%s]" % shorten(body))
        return scope.environ.get(args[0], " ".join(args[1:]))
    if cmd == "anon":
        if not args:
            raise SubstitutionError("$(anon var) must specify a name [%s]" % shorten(body))
        if len(args) > 1:
            raise SubstitutionError("$(anon var) may only specify one name [%s]" % shorten(body))
        return _anon(args[0], scope)
    # dirname
    return _dirname(scope)


def _arg(name: str, scope: SubstitutionScope) -> str:
    try:
        value = scope.args[name]
    except KeyError:
        raise ArgNotSet(name) from None
    scope.used_args.add(name)
    return value


def _env(name: str, scope: SubstitutionScope) -> str:
    try:
        return scope.environ[name]
    except KeyError:
        raise SubstitutionError("environment variable '%s' is not set" % name) from None


def _anon(id_: str, scope: SubstitutionScope) -> str:
    name = scope.anon.get(id_)
    if name is None:
        names = scope.budget.anon_names
        name = scope.anon[id_] = anonymous_name(id_) if names is None else names.name(id_, scope.filename)
    return name


def _dirname(scope: SubstitutionScope) -> str:
    if not scope.filename:
        raise SubstitutionError("Cannot substitute $(dirname), no file/directory information available.")
    return os.path.abspath(os.path.dirname(scope.filename))


def _find(resolved: str, body: str, args: tuple[str, ...], scope: SubstitutionScope) -> str:
    """roslaunch's step: the first copy of `$(find pkg)` and the path after it, up to a space, replaced."""
    cmd = "$(%s)" % body
    i = resolved.find(cmd)
    before, after = resolved[:i], resolved[i + len(cmd):]
    j = after.find(" ")
    path, rest = (after, "") if j < 0 else (after[:j], after[j:])
    return before + _find_value(body, args, path, scope) + rest


def _find_value(body: str, args: tuple[str, ...], path: str, scope: SubstitutionScope) -> str:
    """`$(find pkg)path`: the path decides between executable, share file and source dir."""
    if len(args) != 1:
        raise SubstitutionError("$(find pkg) command only accepts one argument [%s]" % shorten(body))
    path = path.replace("\\", "/")
    if path.startswith("/"):
        path = path[1:]
    if path:
        return scope.find_resource(args[0], path)
    return scope.find_package(args[0])


# ---------------------------------------------------------------------------
# $(eval ...)

# roslaunch's names in $(eval), looked up before the args: its constants and every name of
# the math module (sandbox.MATH: xml/sandbox.py bounds the few math functions that could run long).
_ROSLAUNCH_CONSTANTS: dict[str, Any] = {"true": True, "false": False, "True": True, "False": False}


# roslaunch's functions in $(eval), each made for the scope when an expression names it
# (named functions, not lambdas: a misuse like `arg()` is reported with the function's name)
def _eval_arg(scope: SubstitutionScope) -> Callable[[str], Any]:
    def arg(name: str) -> Any:
        return auto_value(_arg(name, scope))
    return arg


def _eval_env(scope: SubstitutionScope) -> Callable[[str], str]:
    def env(name: str) -> str:
        return _env(name, scope)
    return env


def _eval_optenv(scope: SubstitutionScope) -> Callable[..., str]:
    def optenv(name: str, default: str = "") -> str:
        return scope.environ.get(name, default)
    return optenv


def _eval_anon(scope: SubstitutionScope) -> Callable[[str], str]:
    def anon(id_: str) -> str:
        return _anon(id_, scope)
    return anon


def _eval_dirname(scope: SubstitutionScope) -> Callable[[], str]:
    def dirname() -> str:
        return _dirname(scope)
    return dirname


_SCOPE_FUNCTIONS: dict[str, Callable[[SubstitutionScope], Any]] = {
    "arg": _eval_arg, "env": _eval_env, "optenv": _eval_optenv, "anon": _eval_anon, "dirname": _eval_dirname,
    "find": lambda scope: scope.find_package}


_sandbox: Any = None  # xml/sandbox.py, once the first $(eval) has imported it


def _import_sandbox() -> Any:
    # (imported by the first $(eval): the sandbox and `ast` cost ~2.5 ms to import, and most launches have
    # none; then kept, for an import statement is ~1 us at each of a big launch's thousand $(eval)s)
    global _sandbox
    import launcher.xml.sandbox
    _sandbox = launcher.xml.sandbox
    return _sandbox


# An expression that reads only args (by name or by `arg('literal')`), math, constants and builtins is a
# function of those args' values: a launch tree evaluates the same few such texts over the same args again
# and again (an included file's nodes, each include given the same args). Its text is kept by the values of
# the args it can read, with the args an evaluation did read (marked used again at each reuse). Anything
# that can read more (env, optenv, find, dirname, anon: the environment, the disk, names made) or that
# failed is evaluated every time.
_EVAL_VALUES: dict[tuple, tuple[str, tuple[str, ...]]] = {}
_EVAL_READS: dict[str, tuple[str, ...] | None] = {}  # expr -> the arg names its value depends on (None: not kept)
_EVAL_VALUES_MAX = 16384
_NO_ARG = object()  # (an arg not set, in a key)


def _arg_reads(expr: str, sandbox: Any) -> tuple[str, ...] | None:
    reads = _EVAL_READS.get(expr, _NO_ARG)
    if reads is _NO_ARG:
        try:
            found = sandbox.names_read(expr, "arg")
        except sandbox.EvalError:
            found = None  # (not an expression: evaluating it says why, every time)
        if found is None or any(n in _SCOPE_FUNCTIONS and n != "arg" for n in found[0]):
            reads = None
        else:
            reads = tuple(dict.fromkeys(found[0] + found[1]))  # (any name may be an arg: a value can shadow str)
        if len(_EVAL_READS) < _EVAL_VALUES_MAX:
            _EVAL_READS[expr] = reads
    return reads  # type: ignore[return-value]


def evaluate(expr: str, scope: SubstitutionScope) -> str:
    """`$(eval expr)`: str() of the expression, evaluated by the sandbox over roslaunch's names."""
    # roslaunch's own refusal, kept for its message (the sandbox needs no such rule)
    if "__" in expr:
        raise SubstitutionError("$(eval ...) may not contain double underscore expressions")
    sandbox = _sandbox if _sandbox is not None else _import_sandbox()
    reads = _arg_reads(expr, sandbox)
    if reads is None:
        return _evaluate(expr, scope, sandbox)
    args = scope.args
    key = (expr,) + tuple([args.get(name, _NO_ARG) for name in reads])
    kept = _EVAL_VALUES.get(key)
    if kept is not None:
        scope.used_args.update(kept[1])
        return kept[0]
    # (the args this evaluation reads, told apart from those the load had read before)
    shared_used = scope.used_args
    scope.used_args = used = set()
    try:
        text = _evaluate(expr, scope, sandbox)
    finally:
        scope.used_args = shared_used
        shared_used |= used
    if len(_EVAL_VALUES) < _EVAL_VALUES_MAX:
        _EVAL_VALUES[key] = (text, tuple(used))
    return text


def _evaluate(expr: str, scope: SubstitutionScope, sandbox: Any) -> str:
    """str() of the expression's value, evaluated by the sandbox."""
    def lookup(name: str) -> Any:  # roslaunch's _DictWrapper: its names, then the args auto-typed
        if name in _ROSLAUNCH_CONSTANTS:
            return _ROSLAUNCH_CONSTANTS[name]
        if name in sandbox.MATH:
            return sandbox.MATH[name]
        make = _SCOPE_FUNCTIONS.get(name)
        if make is not None:
            return make(scope)
        if name not in scope.args:
            return sandbox.NOT_FOUND  # (not an arg: the sandbox goes on to its builtins)
        scope.used_args.add(name)
        return auto_value(scope.args[name])

    try:
        return str(sandbox.evaluate(expr, lookup))
    except sandbox.EvalError as e:
        raise SubstitutionError("$(eval %s) failed: %s" % (shorten(expr.strip()), e)) from None
    except ValueError as e:  # str() of a value Python will not print (an int past its digit limit)
        raise SubstitutionError("$(eval %s) failed: %s" % (shorten(expr.strip()), e)) from None
