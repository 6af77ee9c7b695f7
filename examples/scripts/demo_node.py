"""What the demo nodes share: their ROS name from the command line, and parameters from the master over XML-RPC.

Plain Python (standard library only), so the demo runs where ROS is not
installed: `launch` gives each node ROS_MASTER_URI, ROS_NAMESPACE and
`__name:=`, as roslaunch does, and these helpers use them.
"""

from __future__ import annotations

import os
import sys
import xmlrpc.client


class DemoNode:
    def __init__(self, default_name: str):
        args = dict(a.split(":=", 1) for a in sys.argv[1:] if ":=" in a)
        ns = os.environ.get("ROS_NAMESPACE", "").strip("/")
        base = args.get("__name", default_name)
        self.name = "/" + "/".join(p for p in (ns, base) if p)
        self.master = xmlrpc.client.ServerProxy(os.environ.get("ROS_MASTER_URI", "http://localhost:11311/"))

    def param(self, key: str, default=None):
        """getParam; `~key` is private to this node."""
        if key.startswith("~"):
            key = self.name + "/" + key[1:]
        elif not key.startswith("/"):
            key = self.name.rsplit("/", 1)[0] + "/" + key
        code, _msg, value = self.master.getParam(self.name, key)
        return value if code == 1 else default

    def say(self, text: str) -> None:
        print("[%s] %s" % (self.name, text), flush=True)
