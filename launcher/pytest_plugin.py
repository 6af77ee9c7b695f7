"""The pytest plugin (entry point `pytest11`): the `ros_launch` fixture, a `launcher.api.Launch` per call, stopped after the test.

    def test_talker(ros_launch):
        launch = ros_launch("my_pkg", "talker.launch", "rate:=10")
        launch.wait_for_publisher("/chatter")
"""

from __future__ import annotations

from typing import Any, Callable, Iterator

import pytest

from launcher.api import Launch


@pytest.fixture
def ros_launch() -> Iterator[Callable[..., Launch]]:
    """A factory: `ros_launch(*words, **options)` starts a launch (its own master on a free port) and
    returns it; every launch it started is stopped when the test ends."""
    started: list[Launch] = []

    def start(*words: str, **options: Any) -> Launch:
        launch = Launch(*words, **options)
        started.append(launch)
        return launch.start()

    yield start
    for launch in reversed(started):
        launch.stop()
