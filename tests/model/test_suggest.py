"""Close matches for a name a user almost got right: the namespace left out, a typo, nothing close."""

from __future__ import annotations

from launcher.model.suggest import close_matches, did_you_mean, near_file


def test_a_node_name_without_its_namespace_finds_the_node():
    assert did_you_mean("talker", ["/r2/listener", "/r2/talker"]) == "did you mean /r2/talker?"
    assert did_you_mean("/talker", ["/r2/talker", "/r3/talker", "/x"]) == "did you mean /r2/talker or /r3/talker?"


def test_typos_in_names_args_packages_and_files():
    assert close_matches("robto", ["robot", "use_sim_time"]) == ["robot"]
    assert close_matches("/r2/talkr", ["/r2/talker", "/r2/listener"]) == ["/r2/talker"]
    assert close_matches("rospy_tutorals", ["rospy", "rospy_tutorials", "roscpp_tutorials"]) == \
        ["rospy_tutorials", "roscpp_tutorials"]
    # a far worse match is noise beside a close one
    assert close_matches("bringup.lanch", ["sim.launch", "bringup.launch"]) == ["bringup.launch"]


def test_nothing_close_says_nothing():
    assert did_you_mean("zzz", ["/r2/talker", "/r2/listener"]) == ""
    assert did_you_mean("", ["a"]) == "" and did_you_mean("a", []) == ""
    assert did_you_mean("robot", ["robot"]) == ""  # (the name itself is no suggestion)


def test_at_most_three_best_first():
    found = close_matches("node", ["nodes", "node1", "node2", "node3", "nod"])
    assert len(found) == 3 and set(found) <= {"nodes", "node1", "node2", "node3", "nod"}


def test_near_file(tmp_path):
    (tmp_path / "bringup.launch").write_text("<launch/>")
    assert near_file(str(tmp_path / "bringup.lanch")) == "did you mean bringup.launch?"
    assert near_file(str(tmp_path / "nothing_like_it.xml")) == ""
    assert near_file(str(tmp_path / "no_such_dir" / "a.launch")) == ""
    (tmp_path / "launcher").mkdir()  # (a folder is no file: never offered for one)
    assert near_file(str(tmp_path / "launche")) == ""
