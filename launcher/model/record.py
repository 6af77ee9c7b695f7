"""Immutable records written as annotated classes: `@record class Node: name: str ...` is a `collections.namedtuple`.

What `typing.NamedTuple` makes of the same class statement (the same tuple subclass, built
by position in C, compared, hashed and printed by field), without its cost on the way to
`launch --nodes`: importing `typing` is ~3 ms, and its class statement turns each annotation
(text, under `from __future__ import annotations`) into a ForwardRef by compiling it, ~1.5 ms
for a record of 25 fields. Here an annotation stays the text it is, for the reader.

A field is a name with an annotation, in order; its default is the value the class body gives
it, and the fields with a default come last. The class body's methods, properties and
docstring are the record's; `super()` is not available in them (the record is a new class).
"""

from __future__ import annotations

import collections

# what the class statement made for itself, which the record has its own of
_NOT_COPIED = frozenset(("__dict__", "__weakref__", "__module__", "__qualname__", "__slots__"))


def record(cls: type) -> type:
    """The record (a namedtuple class of the same name and module) that the annotated class `cls` describes."""
    body = cls.__dict__
    fields = tuple(body.get("__annotations__", {}))
    defaults = [body[f] for f in fields if f in body]
    required = fields[:len(fields) - len(defaults)]
    if any(f in body for f in required):
        raise TypeError("record %s: the fields with a default must come last" % cls.__name__)
    made = collections.namedtuple(cls.__name__, fields, defaults=defaults, module=cls.__module__)
    for name, value in body.items():
        if name not in _NOT_COPIED and name not in fields:  # (a field's default is the record's, not a class attribute)
            setattr(made, name, value)
    made.__qualname__ = cls.__qualname__
    return made
