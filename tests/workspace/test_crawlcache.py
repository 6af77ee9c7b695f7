"""The package crawl cache: reused while the tree is unchanged, and never wrong after a package is added, removed, moved or renamed."""

from __future__ import annotations

import os
import time

import pytest

from launcher.workspace import packages as packages_mod
from launcher.workspace.packages import PackageIndex, PackageNotFound

MANIFEST = ('<?xml version="1.0"?>\n<package format="2"><name>%s</name><version>0.0.1</version>'
            '<description>d</description><maintainer email="m@e.com">m</maintainer><license>BSD</license></package>\n')


def make_pkg(path, name):
    path.mkdir(parents=True, exist_ok=True)
    (path / "package.xml").write_text(MANIFEST % name)


def settle(root):
    """Date everything an hour back, as a tree that was not just written is."""
    old = time.time() - 3600
    for d, dirs, files in os.walk(root):
        for name in files:
            os.utime(os.path.join(d, name), (old, old))
        os.utime(d, (old, old))


@pytest.fixture
def ws(tmp_path):
    root = tmp_path / "ws"
    for folder in ("a", "b"):
        for i in range(3):
            make_pkg(root / folder / ("%s%d" % (folder, i)), "pkg_%s%d" % (folder, i))
    settle(root)
    return root


@pytest.fixture
def reads(monkeypatch, tmp_path):
    """How many manifests of the test's tree the crawl parses (/usr/share is on the path too)."""
    count = [0]
    real = packages_mod._package_name

    def counting(path):
        count[0] += path.startswith(str(tmp_path))
        return real(path)
    monkeypatch.setattr(packages_mod, "_package_name", counting)
    return count


def index(ws, tmp_path):
    return PackageIndex({"ROS_PACKAGE_PATH": str(ws), "ROS_HOME": str(tmp_path / "home")})


def test_a_settled_tree_is_read_from_the_cache(ws, tmp_path, reads):
    first = index(ws, tmp_path).packages()
    assert reads[0] == 6
    assert os.path.exists(tmp_path / "home/launcher/package_crawl_cache.marshal")
    again = index(ws, tmp_path).packages()
    assert reads[0] == 6  # nothing parsed the second time
    assert again == first


def test_an_added_package_is_found(ws, tmp_path):
    index(ws, tmp_path).packages()
    make_pkg(ws / "a/new", "pkg_new")
    assert index(ws, tmp_path).get_path("pkg_new") == str(ws / "a/new")


def test_a_package_added_deeper_is_found(ws, tmp_path):
    index(ws, tmp_path).packages()
    make_pkg(ws / "b/deeper/still/new", "pkg_deep")
    assert index(ws, tmp_path).get_path("pkg_deep") == str(ws / "b/deeper/still/new")


def test_a_removed_package_is_gone(ws, tmp_path):
    index(ws, tmp_path).packages()
    (ws / "a/a1/package.xml").unlink()
    os.rmdir(ws / "a/a1")
    with pytest.raises(PackageNotFound):
        index(ws, tmp_path).get_path("pkg_a1")


def test_a_moved_package_is_found_where_it_is_now(ws, tmp_path):
    index(ws, tmp_path).packages()
    os.rename(ws / "a/a2", ws / "b/a2")
    assert index(ws, tmp_path).get_path("pkg_a2") == str(ws / "b/a2")


def test_a_renamed_package_has_its_new_name(ws, tmp_path):
    index(ws, tmp_path).packages()
    (ws / "b/b0/package.xml").write_text(MANIFEST % "pkg_zz")  # same length, in place
    ix = index(ws, tmp_path)
    assert ix.get_path("pkg_zz") == str(ws / "b/b0")
    with pytest.raises(PackageNotFound):
        ix.get_path("pkg_b0")


def test_catkin_ignore_hides_a_folder(ws, tmp_path):
    index(ws, tmp_path).packages()
    (ws / "b/CATKIN_IGNORE").write_text("")
    with pytest.raises(PackageNotFound):
        index(ws, tmp_path).get_path("pkg_b1")


def test_a_tree_changed_right_before_the_crawl_is_not_trusted(ws, tmp_path, reads):
    make_pkg(ws / "a/fresh", "pkg_fresh")  # modified now: within the clock tick of the crawl
    index(ws, tmp_path).packages()
    index(ws, tmp_path).packages()
    assert reads[0] == 14  # crawled twice


def test_a_broken_cache_file_is_a_crawl(ws, tmp_path, reads):
    path = tmp_path / "home/launcher/package_crawl_cache.marshal"
    path.parent.mkdir(parents=True)
    path.write_bytes(b"{not marshal")
    assert index(ws, tmp_path).get_path("pkg_a0") == str(ws / "a/a0")


def test_a_package_ignored_in_its_own_directory_is_gone(ws, tmp_path):
    index(ws, tmp_path).packages()
    (ws / "a/a0/CATKIN_IGNORE").write_text("")
    with pytest.raises(PackageNotFound):
        index(ws, tmp_path).get_path("pkg_a0")


def test_a_package_whose_manifest_is_gone_is_gone(ws, tmp_path):
    index(ws, tmp_path).packages()
    (ws / "b/b2/package.xml").unlink()
    with pytest.raises(PackageNotFound):
        index(ws, tmp_path).get_path("pkg_b2")


def test_a_full_listing_sees_a_rename_in_place(ws, tmp_path):
    index(ws, tmp_path).packages()
    (ws / "a/a1/package.xml").write_text(MANIFEST % "pkg_yy")  # same length, in place
    listed = index(ws, tmp_path).packages()
    assert listed.get("pkg_yy") == str(ws / "a/a1") and "pkg_a1" not in listed


def test_a_lookup_checks_the_folders_and_its_own_package_only(ws, tmp_path, monkeypatch, reads):
    """The point of the cache: a launch that uses one package of a big tree does not stat every package."""
    for i in range(40):
        make_pkg(ws / "c" / ("c%d" % i), "pkg_c%d" % i)
    settle(ws)
    index(ws, tmp_path).packages()
    parsed = reads[0]
    stats = []
    real_stat = os.stat

    def counting_stat(path, *args, **kwargs):
        if str(path).startswith(str(ws)):
            stats.append(str(path))
        return real_stat(path, *args, **kwargs)
    monkeypatch.setattr(os, "stat", counting_stat)
    assert index(ws, tmp_path).get_path("pkg_c7") == str(ws / "c/c7")
    assert reads[0] == parsed  # nothing parsed: the cache answered
    package_dirs = {str(ws / f / n) for f, ns in (("a", 3), ("b", 3), ("c", 40)) for n in
                    ("%s%d" % (f, i) for i in range(ns))}
    checked = {p for p in stats if p in package_dirs or p.endswith("package.xml")}
    assert checked == {str(ws / "c/c7"), str(ws / "c/c7/package.xml")}, sorted(checked)
    assert {str(ws), str(ws / "a"), str(ws / "b"), str(ws / "c")} <= set(stats)
