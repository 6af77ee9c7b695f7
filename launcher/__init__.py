"""launcher: a roslaunch/roscore equivalent for ROS 1."""

__version__ = "0.1.0"
