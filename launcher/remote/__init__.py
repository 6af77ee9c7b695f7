"""Nodes on other machines: the parent side of roslaunch's remote protocol over the system's OpenSSH (the child side is launcher/remote/child.py)."""
