"""shellwords.split: shlex.split's words and errors, in linear time."""

from __future__ import annotations

import shlex

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from launcher.model import shellwords

_PARTS = ["a", "b c", " ", "\t", "\n", "\r", "'", '"', "\\", "\\\\", '\\"', "\\'", "x y", "''", '""', "\x0b", "é",
          "#", ";", "$(", "--x=1", "'a b'", '"a \\" b"']


@settings(max_examples=3000, deadline=None)
@given(st.lists(st.sampled_from(_PARTS), max_size=12))
def test_same_words_and_errors_as_shlex(parts):
    text = "".join(parts)
    try:
        expected = shlex.split(text)
    except ValueError as e:
        with pytest.raises(ValueError, match=str(e)):
            shellwords.split(text)
        return
    assert shellwords.split(text) == expected


@pytest.mark.parametrize("text", ["x" * 400_000, "'" + "y " * 200_000 + "'", '"' + "\\\\" * 100_000 + '"'])
def test_one_long_word_is_split_in_linear_time(text):
    """shlex adds a word up a character at a time (`token = token + c`): a 1 MB word took minutes."""
    import time
    start = time.process_time()
    words = shellwords.split(text)
    assert len(words) == 1 and time.process_time() - start < 2.0
