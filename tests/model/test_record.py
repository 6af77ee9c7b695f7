"""model/record.py: an annotated class made an immutable namedtuple, as typing.NamedTuple makes it."""

from __future__ import annotations

import pickle
import typing

import pytest

from launcher.model.record import record


@record
class Pose:
    """Where a thing is."""

    frame: str
    x: float = 0.0
    tags: tuple[str, ...] = ()

    @property
    def moved(self) -> bool:
        return self.x != 0.0

    @classmethod
    def at(cls, x: float) -> Pose:
        return cls("map", x)


class PoseNT(typing.NamedTuple):
    """Where a thing is."""

    frame: str
    x: float = 0.0
    tags: tuple[str, ...] = ()


def test_a_record_is_what_typing_namedtuple_makes_of_the_same_class():
    assert Pose._fields == PoseNT._fields == ("frame", "x", "tags")
    assert Pose._field_defaults == PoseNT._field_defaults == {"x": 0.0, "tags": ()}
    for args in (("odom",), ("odom", 1.5), ("odom", 1.5, ("a",))):
        mine, theirs = Pose(*args), PoseNT(*args)
        assert tuple(mine) == tuple(theirs) and repr(mine) == repr(theirs).replace("PoseNT", "Pose")
        assert hash(mine) == hash(theirs) and mine == theirs
    assert Pose(frame="a", x=2.0) == Pose("a", 2.0) and Pose("a")._replace(x=3.0) == Pose("a", 3.0)
    assert Pose.__doc__ == "Where a thing is." and Pose.__name__ == "Pose" and Pose.__module__ == __name__
    assert Pose.__annotations__ == {"frame": "str", "x": "float", "tags": "tuple[str, ...]"}  # (left as text)
    with pytest.raises(AttributeError):
        Pose("a").x = 1.0  # type: ignore[misc]
    with pytest.raises(AttributeError):
        Pose("a").other = 1  # type: ignore[attr-defined]
    with pytest.raises(TypeError):
        Pose()  # type: ignore[call-arg]
    assert pickle.loads(pickle.dumps(Pose("a", 1.0))) == Pose("a", 1.0)


def test_the_class_bodys_methods_are_the_records():
    assert Pose.at(2.0) == Pose("map", 2.0) and type(Pose.at(2.0)) is Pose
    assert Pose("a", 1.0).moved and not Pose("a").moved


def test_fields_with_a_default_come_last():
    with pytest.raises(TypeError, match="come last"):
        @record
        class Bad:
            a: int = 0
            b: str
