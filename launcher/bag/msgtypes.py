"""Message type names as bags and ROS 1 say them (`std_msgs/String`) and as rosbags does (`std_msgs/msg/String`)."""

from __future__ import annotations


def ros1_type(msgtype: str) -> str:
    """rosbags names types the ROS 2 way (`std_msgs/msg/String`); bags and ROS 1 say `std_msgs/String`."""
    pkg, _, rest = msgtype.partition("/msg/")
    return "%s/%s" % (pkg, rest) if rest else msgtype


def rosbags_type(mtype: str) -> str:
    """The type rosbags' writer takes (`std_msgs/msg/String`) for a ROS 1 name."""
    pkg, sep, name = mtype.partition("/")
    return "%s/msg/%s" % (pkg, name) if sep and "/" not in name else mtype
