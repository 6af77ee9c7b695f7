"""Nodes on other machines: roslaunch's remote protocol (parent and child XML-RPC APIs) over the system's OpenSSH."""
