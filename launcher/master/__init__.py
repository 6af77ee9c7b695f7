"""The embedded ROS master: its server (`server`), the Master and Parameter Server APIs (`api`), the graph
(`registry`), the callbacks to nodes (`outbox`, `notify`). Empty, so that a pure module of the package (`outbox`)
loads no I/O through it."""
