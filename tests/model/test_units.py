"""Sizes: one rule (README, "Units") for `--log-max-size`, `--log-check-threshold`, the launch attributes and messages."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from launcher.cli import launch as cli
from launcher.output import logdir
from launcher.model.runopts import RunOptions
from launcher.run.load import load_plan
from launcher.model.units import format_size, parse_size


@pytest.mark.parametrize("text, size", [
    ("100MB", 100_000_000), ("500MB", 500 * 10**6), ("1GB", 10**9), ("2g", 2 * 10**9), ("200k", 200_000),
    ("2 kB", 2000), ("1tb", 10**12), ("1GiB", 2**30), ("1.5GiB", 3 * 2**29), ("3mib", 3 * 2**20), ("1.5KiB", 1536),
    ("2Ti", 2 * 2**40), ("4096", 4096), ("10B", 10), ("0", 0), (" 7 ", 7), (".5k", 500), ("5.", 5),
    ("0.3GB", 300_000_000), ("1.0000001MiB", 2**20), ("1152921504606846976", 2**60),
])
def test_sizes_read_by_the_readme_rule(text, size):
    assert parse_size(text) == size


@pytest.mark.parametrize("text", ["lots", "", "MB", ".", "1.2.3MB", "5 pb", "-3k", "1 G B", "1XB", "1e3", "nan"])
def test_bad_sizes_say_what_a_size_looks_like(text):
    with pytest.raises(ValueError, match=r"^invalid size \[%s\]: expected a size such as 500MB" % text):
        parse_size(text)


@pytest.mark.parametrize("size, text", [
    (0, "0B"), (999, "999B"), (1000, "1kB"), (1024, "1KiB"), (1536, "1.5KiB"), (10_000, "10kB"),
    (100_000_000, "100MB"), (612_345_678, "612.3MB"), (2**30, "1GiB"), (3 * 2**29, "1.5GiB"), (10**9, "1GB"),
    (2**40, "1TiB"), (5 * 10**12, "5TB"), (1_024_000, "1000KiB"),
])
def test_sizes_printed(size, text):
    assert format_size(size) == text


@given(st.integers(min_value=0, max_value=2**50))
def test_a_printed_size_reads_back_within_a_twentieth_of_its_unit(n):
    back = parse_size(format_size(n))
    assert abs(back - n) <= max(n, 1000) * 0.05 + 1


@given(st.sampled_from(["k", "M", "G", "T"]), st.integers(min_value=1, max_value=99_999), st.booleans())
def test_a_size_written_in_whole_units_prints_exactly(prefix, count, binary):
    size = parse_size("%d%s%sB" % (count, prefix, "i" if binary else ""))
    assert parse_size(format_size(size)) == size


def _plan(tmp_path, argv, node_attrs=""):
    launch = tmp_path / "a.launch"
    launch.write_text('<launch><node name="n" pkg="p" type="t" %s/></launch>' % node_attrs)
    opts = cli.build_parser().parse_args(argv + [str(launch)])
    return load_plan(RunOptions.from_args(opts))


def test_log_max_size_option_and_attribute_mean_the_same_bytes(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path))
    plan = _plan(tmp_path, ["--log-max-size", "100MB"], 'log_max_size="100MB"')
    assert plan.log_max_size == plan.config.nodes[0].policy.log_max_size == 100_000_000


def test_default_log_check_threshold_is_roslaunchs_2_to_the_30_and_keeps_its_words(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path))
    plan = _plan(tmp_path, [])
    assert plan.log_threshold == logdir.DEFAULT_THRESHOLD == 2**30
    assert plan.log_max_size == 100_000_000  # the default --log-max-size, 100MB
    assert _plan(tmp_path, ["--log-check-threshold", "1GB"]).log_threshold == 10**9


def test_a_measured_size_is_never_an_exact_binary_unit():
    """A process's RSS is a number of 4 KiB pages: shown to a tenth of a decimal unit, as the web page does."""
    assert format_size(8209 * 4096) == "32836KiB"
    assert format_size(8209 * 4096, measured=True) == "33.6MB"
    assert format_size(100_000_000, measured=True) == "100MB" and format_size(512, measured=True) == "512B"
