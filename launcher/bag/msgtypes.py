"""Message type names as bags and ROS 1 say them (`std_msgs/String`) and as rosbags' writer takes them
(`std_msgs/msg/String`)."""

from __future__ import annotations


def rosbags_type(mtype: str) -> str:
    """The type rosbags' writer takes (`std_msgs/msg/String`) for a ROS 1 name."""
    pkg, sep, name = mtype.partition("/")
    return "%s/msg/%s" % (pkg, name) if sep and "/" not in name else mtype
