"""Package, executable and `$(find)` lookup, on small package trees built in tmp_path."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from launcher.workspace import packages as packages_mod
from launcher.model.errors import LaunchError
from launcher.workspace.packages import ExecutableNotFound, MultipleResources, PackageIndex, PackageNotFound

from helpers import COMPAT


def make_pkg(root, rel, name=None, meta=False, manifest=False):
    d = root / rel
    d.mkdir(parents=True, exist_ok=True)
    if manifest:
        (d / "manifest.xml").write_text("<package/>")
    else:
        export = "<export><metapackage/></export>" if meta else ""
        (d / "package.xml").write_text(
            '<?xml version="1.0"?>\n<package format="2">\n  <name>\n  %s  </name>\n  <version>0.0.1</version>\n'
            '  <description>d</description>\n  <maintainer email="m@example.com">m</maintainer>\n'
            '  <license>BSD</license>%s\n</package>\n'
            % (name or os.path.basename(rel), export))
    return d


def make_exe(path, mode=0o755, text="#!/bin/sh\n"):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    path.chmod(mode)
    return path


def index(*paths, workspaces=(), ros_root=None):
    env = {"ROS_PACKAGE_PATH": os.pathsep.join(str(p) for p in paths),
           "CMAKE_PREFIX_PATH": os.pathsep.join(str(w) for w in workspaces),
           "ROS_HOME": str(paths[0]) + "-roshome"}  # (the crawl cache goes beside the tree, not into ~/.ros)
    if ros_root:
        env["ROS_ROOT"] = str(ros_root)
    return PackageIndex(environ=env)


# -- package crawl ---------------------------------------------------------------------------

def test_package_name_comes_from_package_xml_not_directory(tmp_path):
    make_pkg(tmp_path, "src/some_dir", name="zz_real_name")
    ix = index(tmp_path)
    assert ix.get_path("zz_real_name") == str(tmp_path / "src/some_dir")
    with pytest.raises(PackageNotFound):
        ix.get_path("some_dir")


@pytest.mark.parametrize("xml,expected", [
    (b"<package><name> pkg\n</name></package>", ("pkg", False)),
    # the first <name> under the root, its own text only (CDATA and entities included)
    (b"<package><x><name>no</name></x><name>a<b>x</b>c<![CDATA[d]]>&amp;</name><name>z</name></package>",
     ("acd&", False)),
    (b"<package><name>m</name><export><metapackage/></export></package>", ("m", True)),
    (b"<package><name>m</name><export><x><metapackage/></x></export></package>", ("m", False)),
    # namespaces as minidom reports them: a default namespace changes nothing, a prefix does
    (b'<package xmlns="urn:x"><name>n</name></package>', ("n", False)),
    (b'<p:package xmlns:p="urn:x"><p:name>n</p:name><name>m</name></p:package>', ("m", False)),
    (b"<package><q:name>unbound prefix</q:name></package>", (None, False)),
    (b"<package><version>1</version></package>", (None, False)),
    (b"<package><name>x</package>", (None, False)),
])
def test_package_xml_name_and_metapackage(xml, expected):
    assert packages_mod.read_package_xml(xml) == expected


def test_packages_does_not_import_the_launch_xml_loader():
    """package.xml is read by the package index itself: `packages` and `xml` import in one direction only."""
    code = "import sys, launcher.workspace.packages; print(sorted(m for m in sys.modules if m.startswith('launcher.xml')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_first_ros_package_path_entry_wins(tmp_path):
    a = make_pkg(tmp_path, "a/zz_pkg")
    make_pkg(tmp_path, "b/zz_pkg")
    make_pkg(tmp_path, "b/zz_only_b")
    assert index(tmp_path / "a", tmp_path / "b").get_path("zz_pkg") == str(a)
    assert index(tmp_path / "b", tmp_path / "a").get_path("zz_pkg") == str(tmp_path / "b/zz_pkg")
    assert index(tmp_path / "a", tmp_path / "b").get_path("zz_only_b") == str(tmp_path / "b/zz_only_b")


def test_ros_root_comes_before_ros_package_path(tmp_path):
    make_pkg(tmp_path, "root/zz_pkg")
    make_pkg(tmp_path, "rpp/zz_pkg")
    ix = index(tmp_path / "rpp", ros_root=tmp_path / "root")
    assert ix.get_path("zz_pkg") == str(tmp_path / "root/zz_pkg")
    assert ix.ros_paths[0] == str(tmp_path / "root")


def test_crawl_does_not_descend_into_a_package(tmp_path):
    make_pkg(tmp_path, "outer", name="zz_outer")
    make_pkg(tmp_path, "outer/inner", name="zz_inner")
    ix = index(tmp_path)
    assert ix.get_path("zz_outer") == str(tmp_path / "outer")
    with pytest.raises(PackageNotFound):
        ix.get_path("zz_inner")


@pytest.mark.parametrize("marker", ["CATKIN_IGNORE", "rospack_nosubdirs"])
def test_ignore_markers_hide_subtrees(tmp_path, marker):
    make_pkg(tmp_path, "ws/hidden/zz_pkg")
    (tmp_path / "ws/hidden" / marker).write_text("")
    make_pkg(tmp_path, "ws/visible/zz_other")
    ix = index(tmp_path / "ws")
    assert "zz_other" in ix.packages()
    with pytest.raises(PackageNotFound):
        ix.get_path("zz_pkg")


def test_catkin_ignore_inside_package_dir_hides_the_package(tmp_path):
    d = make_pkg(tmp_path, "zz_pkg")
    (d / "CATKIN_IGNORE").write_text("")
    with pytest.raises(PackageNotFound):
        index(tmp_path).get_path("zz_pkg")


def test_hidden_directories_are_not_crawled(tmp_path):
    make_pkg(tmp_path, ".hidden/zz_pkg")
    with pytest.raises(PackageNotFound):
        index(tmp_path).get_path("zz_pkg")


def test_rosbuild_manifest_package_is_named_after_its_directory(tmp_path):
    make_pkg(tmp_path, "zz_old_style", manifest=True)
    assert index(tmp_path).get_path("zz_old_style") == str(tmp_path / "zz_old_style")


def test_metapackages_are_not_packages_but_stop_the_crawl(tmp_path):
    make_pkg(tmp_path, "zz_meta", meta=True)
    make_pkg(tmp_path, "zz_meta/zz_under_meta")
    ix = index(tmp_path)
    for name in ("zz_meta", "zz_under_meta"):
        with pytest.raises(PackageNotFound):
            ix.get_path(name)


def test_unreadable_package_xml_is_skipped_with_a_warning(tmp_path):
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken/package.xml").write_text("<package><name>x</nam")
    make_pkg(tmp_path, "zz_good")
    ix = index(tmp_path)
    assert ix.get_path("zz_good")
    assert any("broken" in w for w in ix.warnings)


def test_package_not_found_is_a_launch_error_worded_like_rospkg(tmp_path):
    ix = index(tmp_path)
    with pytest.raises(PackageNotFound) as err:
        ix.get_path("zz_no_such_package")
    assert isinstance(err.value, LaunchError)
    text = str(err.value)
    assert text.startswith("Resource not found: zz_no_such_package")
    assert "ROS path [0]=%s" % tmp_path in text
    assert text.endswith("ROS path [1]=/usr/share")


def test_symlink_cycle_terminates(tmp_path):
    (tmp_path / "loop").mkdir()
    os.symlink("..", tmp_path / "loop/up")
    make_pkg(tmp_path, "zz_pkg")
    assert index(tmp_path).get_path("zz_pkg") == str(tmp_path / "zz_pkg")


def test_symlinked_package_dir_is_found_under_the_link_path(tmp_path):
    real = make_pkg(tmp_path, "elsewhere/zz_linked")
    (tmp_path / "path").mkdir()
    os.symlink(real, tmp_path / "path/link")
    assert index(tmp_path / "path").get_path("zz_linked") == str(tmp_path / "path/link")


# -- find_node -------------------------------------------------------------------------------

def test_find_node_searches_the_package_recursively(tmp_path):
    d = make_pkg(tmp_path, "zz_pkg")
    exe = make_exe(d / "nodes/deep/er/zz_talker")
    assert index(tmp_path).find_node("zz_pkg", "zz_talker") == str(exe)


def test_find_node_needs_user_read_and_execute_bits(tmp_path):
    d = make_pkg(tmp_path, "zz_pkg")
    make_exe(d / "a/zz_node", mode=0o644)
    make_exe(d / "b/zz_node", mode=0o311)  # x but no r for the user: roslib refuses it
    good = make_exe(d / "c/zz_node", mode=0o500)
    assert index(tmp_path).find_node("zz_pkg", "zz_node") == str(good)


def test_find_node_missing_executable_error(tmp_path):
    make_pkg(tmp_path, "zz_pkg")
    with pytest.raises(ExecutableNotFound) as err:
        index(tmp_path).find_node("zz_pkg", "zz_node")
    assert isinstance(err.value, LaunchError)
    assert str(err.value) == (
        "Cannot locate node of type [zz_node] in package [zz_pkg]. Make sure file exists in package path "
        "and permission is set to executable (chmod +x)")


def test_a_script_without_its_exec_bit_is_named_with_the_fix(tmp_path):
    """roslaunch says only "Cannot locate node"; the file is there, and chmod +x is the fix."""
    d = make_pkg(tmp_path, "zz_pkg")
    script = make_exe(d / "scripts/zz node", mode=0o644)
    with pytest.raises(ExecutableNotFound) as err:
        index(tmp_path).find_node("zz_pkg", "zz node")
    text = str(err.value)
    assert text.startswith("Cannot locate node of type [zz node] in package [zz_pkg].")
    assert "The file [%s] exists but is not executable: run chmod +x '%s'" % (script, script) in text


def test_find_node_requires_the_package_even_if_a_workspace_has_the_executable(tmp_path):
    ws = tmp_path / "ws"
    (ws).mkdir()
    (ws / ".catkin").write_text("")
    make_exe(ws / "lib/zz_pkg/zz_node")
    with pytest.raises(PackageNotFound):
        index(tmp_path / "src", workspaces=[ws]).find_node("zz_pkg", "zz_node")


def test_find_node_prefers_workspace_lib_over_package_dir(tmp_path):
    d = make_pkg(tmp_path, "src/zz_pkg")
    make_exe(d / "scripts/zz_node")
    ws = tmp_path / "ws"
    ws.mkdir()
    (ws / ".catkin").write_text("")
    in_ws = make_exe(ws / "lib/zz_pkg/zz_node")
    assert index(tmp_path / "src", workspaces=[ws]).find_node("zz_pkg", "zz_node") == str(in_ws)


def test_prefix_without_catkin_marker_is_not_a_workspace(tmp_path):
    d = make_pkg(tmp_path, "src/zz_pkg")
    in_pkg = make_exe(d / "zz_node")
    prefix = tmp_path / "plain"
    make_exe(prefix / "lib/zz_pkg/zz_node")
    assert index(tmp_path / "src", workspaces=[prefix]).find_node("zz_pkg", "zz_node") == str(in_pkg)


def test_only_the_first_workspace_with_package_dirs_is_searched(tmp_path):
    d = make_pkg(tmp_path, "src/zz_pkg")
    in_pkg = make_exe(d / "zz_node")
    ws1, ws2 = tmp_path / "ws1", tmp_path / "ws2"
    for ws in (ws1, ws2):
        ws.mkdir()
        (ws / ".catkin").write_text("")
    (ws1 / "share/zz_pkg").mkdir(parents=True)  # ws1 has the package, but not the executable
    make_exe(ws2 / "lib/zz_pkg/zz_node")
    # catkin stops at ws1; roslib then falls back to the package dir, never to ws2
    assert index(tmp_path / "src", workspaces=[ws1, ws2]).find_node("zz_pkg", "zz_node") == str(in_pkg)


def test_find_node_prunes_hidden_dirs_in_package(tmp_path):
    d = make_pkg(tmp_path, "zz_pkg")
    make_exe(d / ".git/zz_node")
    with pytest.raises(ExecutableNotFound):
        index(tmp_path).find_node("zz_pkg", "zz_node")


def test_find_node_dangling_symlink_is_not_an_executable(tmp_path):
    d = make_pkg(tmp_path, "zz_pkg")
    os.symlink(tmp_path / "nowhere", d / "zz_node")
    with pytest.raises(ExecutableNotFound):
        index(tmp_path).find_node("zz_pkg", "zz_node")


def test_many_lookups_walk_each_directory_once(tmp_path, monkeypatch):
    d = make_pkg(tmp_path, "zz_pkg")
    for i in range(5):
        make_exe(d / ("sub%d/node%d" % (i, i)))
    calls = []
    real_scandir = os.scandir

    def counting_scandir(path):
        calls.append(str(path))
        return real_scandir(path)

    monkeypatch.setattr(packages_mod.os, "scandir", counting_scandir)
    ix = index(tmp_path)
    for i in range(5):
        assert ix.find_node("zz_pkg", "node%d" % i).endswith("node%d" % i)
    # the package dir was listed by the package crawl and by one walk for executables
    assert calls.count(str(d)) <= 2
    first_round = len(calls)
    for _ in range(200):
        for i in range(5):
            assert ix.find_node("zz_pkg", "node%d" % i).endswith("node%d" % i)
        with pytest.raises(ExecutableNotFound):
            ix.find_node("zz_pkg", "missing")
    assert len(calls) == first_round + 0, calls[first_round:]


# -- $(find pkg)/rest -----------------------------------------------------------------------

@pytest.fixture
def find_tree(tmp_path):
    src = tmp_path / "src"
    d = make_pkg(src, "zz_pkg")
    make_exe(d / "scripts/tool")
    (d / "data").mkdir()
    (d / "data/only_src.txt").write_text("src")
    (d / "data/both.txt").write_text("src")
    ws = tmp_path / "ws"
    (ws / "share/zz_pkg/data").mkdir(parents=True)
    (ws / ".catkin").write_text("")
    (ws / "share/zz_pkg/data/both.txt").write_text("ws")
    make_exe(ws / "lib/zz_pkg/ws_tool")
    return index(src, workspaces=[ws]), d, ws


def test_find_resource_rules(find_tree):
    ix, d, ws = find_tree
    assert ix.find_resource("zz_pkg") == str(d)
    assert ix.find_resource("zz_pkg", "/") == str(d)
    assert ix.find_resource("zz_pkg", "/data/only_src.txt") == str(d / "data/only_src.txt")
    assert ix.find_resource("zz_pkg", "/data/both.txt") == str(ws / "share/zz_pkg/data/both.txt")
    # executable in the workspace's lib dir by basename, wherever the path points
    assert ix.find_resource("zz_pkg", "/any/dir/ws_tool") == str(ws / "lib/zz_pkg/ws_tool")
    assert ix.find_resource("zz_pkg", "/scripts/tool") == str(d / "scripts/tool")
    # no existence check for the final fallback
    assert ix.find_resource("zz_pkg", "/no/such/file") == str(d / "no/such/file")


def test_find_resource_unknown_package(find_tree):
    ix, _d, _ws = find_tree
    with pytest.raises(PackageNotFound):
        ix.find_resource("zz_nope", "/x")


# -- launch PKG FILE ---------------------------------------------------------------------------

def test_find_launch_file(tmp_path):
    d = make_pkg(tmp_path, "zz_pkg")
    (d / "launch").mkdir()
    (d / "launch/a.launch").write_text("<launch/>")
    (d / "launch/dup.launch").write_text("<launch/>")
    (d / "other").mkdir()
    (d / "other/dup.launch").write_text("<launch/>")
    ix = index(tmp_path)
    assert ix.find_launch_file("zz_pkg", "a.launch") == str(d / "launch/a.launch")
    assert ix.find_launch_file("zz_pkg", "missing.launch") is None
    with pytest.raises(MultipleResources) as err:
        ix.find_launch_file("zz_pkg", "dup.launch")
    assert "multiple files named [dup.launch] in package [zz_pkg]" in str(err.value)
    with pytest.raises(PackageNotFound):
        ix.find_launch_file("zz_nope", "a.launch")


# -- against the reference (rospkg + roslib on the compat corpus) ----------------------------

REF_SCRIPT = r"""
import json, os, sys
import rospkg, roslib.packages
rp = rospkg.RosPack()
out = {"packages": {n: rp.get_path(n) for n in rp.list()}, "nodes": {}, "resources": {}}
for pkg, typ in json.loads(sys.argv[1]):
    try:
        m = roslib.packages.find_node(pkg, typ, rospack=rp)
        out["nodes"]["%s/%s" % (pkg, typ)] = m[0] if m else None
    except rospkg.ResourceNotFound:
        out["nodes"]["%s/%s" % (pkg, typ)] = "NOPKG"
for pkg, name in json.loads(sys.argv[2]):
    try:
        out["resources"]["%s/%s" % (pkg, name)] = roslib.packages.find_resource(pkg, name)
    except rospkg.ResourceNotFound:
        out["resources"]["%s/%s" % (pkg, name)] = "NOPKG"
print(json.dumps(out))
"""


def test_matches_rospkg_and_roslib_on_compat_corpus(ros_env):
    if not os.path.isdir(COMPAT):
        pytest.skip("compat corpus missing")
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_") and k != "CMAKE_PREFIX_PATH"}
    env.update(ROS_PACKAGE_PATH=COMPAT + "/pkgs", CMAKE_PREFIX_PATH=COMPAT + "/ws", PATH=ros_env["path"])
    queries = [("compat_nodes", t) for t in ("talker", "deep_node", "ws_only", "both", "not_exec", "nope")]
    queries += [("pkg", "node1"), ("roslaunch", "roslaunch"), ("rospy", "talker.py"), ("zz_missing", "x")]
    resources = [("compat_cases", "subst_find.launch"), ("roslaunch_compat", "test-arg.xml"),
                 ("compat_nodes", "talker"), ("compat_nodes", "both"), ("compat_cases", "nope.launch"),
                 ("compat_cases", "params.yaml"), ("zz_missing", "x.launch"), ("roslaunch", "roscore.xml")]
    ref = json.loads(subprocess.run([ros_env["python"], "-c", REF_SCRIPT, json.dumps(queries), json.dumps(resources)],
                                    env=env,
                                    capture_output=True, text=True, check=True, timeout=120).stdout)
    ix = PackageIndex(environ=env)
    assert ix.packages() == ref["packages"]
    for pkg, typ in queries:
        try:
            ours = ix.find_node(pkg, typ)
        except ExecutableNotFound:
            ours = None
        except PackageNotFound:
            ours = "NOPKG"
        assert ours == ref["nodes"]["%s/%s" % (pkg, typ)], (pkg, typ)
    for pkg, name in resources:
        expected = ref["resources"]["%s/%s" % (pkg, name)]
        try:
            found = ix.find_launch_file(pkg, name)
            got = [found] if found else []
        except MultipleResources as e:
            got = list(e.matches)
        except PackageNotFound:
            got = "NOPKG"
        assert got == expected, (pkg, name)


CATKIN_REF = r"""
import json, sys
from catkin.find_in_workspaces import find_in_workspaces
out = []
for dirs, project, path, first in json.loads(sys.argv[1]):
    out.append(find_in_workspaces(dirs, project=project, path=path, first_matching_workspace_only=True,
                                  first_match_only=first))
print(json.dumps(out))
"""


def test_catkin_dirs_match_catkin_find_in_workspaces(ros_env, tmp_path):
    # a devel space whose .catkin lists two source spaces, an install space, and a plain prefix
    src1, src2 = tmp_path / "src1", tmp_path / "src2"
    make_pkg(src1, "zz_a")
    make_pkg(src1, "group/zz_b")
    make_pkg(src2, "zz_c")
    (src2 / "ignored").mkdir()
    (src2 / "ignored/CATKIN_IGNORE").write_text("")
    make_pkg(src2, "ignored/zz_d")
    devel = tmp_path / "devel"
    devel.mkdir()
    (devel / ".catkin").write_text("%s;%s;%s" % (src1, src2, src1))
    make_exe(devel / "lib/zz_a/tool")
    install = tmp_path / "install"
    (install / "share/zz_b/cfg").mkdir(parents=True)
    (install / ".catkin").write_text("")
    make_exe(install / "lib/zz_c/other")
    plain = tmp_path / "plain"
    (plain / "share/zz_a").mkdir(parents=True)
    env = {"CMAKE_PREFIX_PATH": os.pathsep.join(str(p) for p in (plain, devel, install)), "ROS_PACKAGE_PATH": ""}
    queries = []
    for project in ("zz_a", "zz_b", "zz_c", "zz_d", "zz_none"):
        for dirs in (["libexec", "share"], ["libexec"], ["share"]):
            queries.append([dirs, project, None, False])
        queries.append([["share"], project, "cfg", True])
        queries.append([["share"], project, "package.xml", True])
    ref = json.loads(subprocess.run([ros_env["python"], "-c", CATKIN_REF, json.dumps(queries)],
                                    env=dict(os.environ, PATH=ros_env["path"], **env), capture_output=True,
                                    text=True, check=True, timeout=120).stdout)
    ix = PackageIndex(environ=env)
    for (dirs, project, path, first), expected in zip(queries, ref):
        ours = ix.catkin_dirs(project, tuple(dirs), path=path, first_match_only=first)
        assert ours == expected, (dirs, project, path)


def test_unreadable_package_xml_is_reported_by_launch(tmp_path):
    """Nothing is silently ignored: the index's warning reaches the user through the loader."""
    import sys
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken/package.xml").write_text("<package><name>x</nam")
    good = make_pkg(tmp_path, "zz_good")
    make_exe(good / "talker")
    launch_file = tmp_path / "a.launch"
    launch_file.write_text('<launch><node pkg="zz_good" type="talker" name="t"/></launch>')
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROS_") and k != "CMAKE_PREFIX_PATH"}
    env["ROS_PACKAGE_PATH"] = str(tmp_path)
    # --args looks up the executable, which crawls the package path
    out = subprocess.run([sys.executable, "-m", "launcher", "--args", "/t", str(launch_file)], env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("zz_good/talker __name:=t")
    assert "ignoring unreadable package manifest %s" % (tmp_path / "broken" / "package.xml") in out.stderr


def test_package_version_is_the_text_of_the_first_version_under_the_root(tmp_path):
    """What `rosversion roslaunch` prints, for roscore's /rosversion (read with expat, not the launch-file loader)."""
    from launcher.workspace.packages import package_version
    manifest = tmp_path / "package.xml"
    manifest.write_text('<?xml version="1.0"?>\n<package format="2"><name>roslaunch</name>\n'
                        '  <export><version>9.9</version></export>\n  <version>1.15.15</version>\n'
                        '  <version>2.0</version>\n</package>\n')
    assert package_version(str(manifest)) == "1.15.15"
    manifest.write_text("<package><name>x</name></package>")
    assert package_version(str(manifest)) is None
    manifest.write_text("<package><version>1.0</package>")
    assert package_version(str(manifest)) is None  # (not well-formed)
    assert package_version(str(tmp_path / "none.xml")) is None
