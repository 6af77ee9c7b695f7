"""What a run runs, as a pure description: the loaded launch, its master URI and environment, its other machines.

A `Plan` is data and what follows from data alone: which nodes run on other
machines (`remote`, `remote_nodes`: the machine names that are other hosts are
given to it), and the checks of the nodes that need nothing but the launch
(`check_nodes`: the bound nodelet loaders, the waits' cycles, the output
waits, respawn with required), and the relations among this machine's nodes
(`relations`). Making one reads the machine, and is
`run.load`'s: the launch files read, the addresses looked up
(`plan.machines`), the settings the other machines need checked against this
machine's address. What a run works out from a plan is `plan/`'s too: each
local node's process spec (`specs.node_specs`), a reload's difference of two
plans (`diff`).
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from launcher.model.config import LaunchConfig, Node
from launcher.model.errors import LaunchError
from launcher.model.units import LOG_CHECK_THRESHOLD
from launcher.plan.order import bind_nodelets, check_cycles, check_output_waits
from launcher.plan.relations import Relations, of as relations_of
from launcher.plan.remote import machine_nodes


class Plan:
    """What a run runs: the loaded launch, its master URI, its environment, which machines are other hosts."""

    def __init__(self, config: LaunchConfig, master_uri: str, environ: Mapping[str, str], *, core: bool = False,
                 packages: Any = None, remote_machines: frozenset[str] = frozenset(),
                 log_threshold: int = LOG_CHECK_THRESHOLD, log_max_size: int = 0, core_port: int = 0,
                 files: Sequence[str] = (), argv: Sequence[str] = (), anon_names: Any = None):
        self.config = config
        self.master_uri = master_uri
        self.environ = environ
        self.core = core  # roscore: an empty launch, our master on `core_port`
        self.packages = packages  # the package index the launch was read with (workspace.packages)
        # the machines of the launch's nodes that are other hosts (plan.machines looked them up)
        self.remote_machines = remote_machines
        self.log_threshold = log_threshold  # the log directory's size that is warned about
        self.log_max_size = log_max_size  # node output logs are rotated past this size (0: never)
        self.core_port = core_port
        # what a reload reads again (run/reload.py): the files, the args, the run's $(anon) names
        # (model.names.AnonNames)
        self.files = list(files)
        self.argv = list(argv)
        self.anon_names = anon_names
        # the parameters as the run's launcher-params.yaml keeps them, when made with the plan (run/apart.py: PyYAML
        # stays out of the launch's memory); None: made when the file is written
        self.params_text: str | None = None

    def remote(self, node: Node) -> bool:
        """Is the node assigned to another machine?"""
        return bool(node.machine_name) and node.machine_name in self.remote_machines

    def remote_nodes(self) -> dict[str, list[Node]]:
        """The nodes to launch on other machines, by machine name."""
        if not self.remote_machines:
            return {}
        return machine_nodes(self.config.nodes, self.config.machines, self.remote)

    @property
    def relations(self) -> Relations:
        """The relations among this machine's nodes (`plan.relations`: bound, stopped before), from their
        policies as `check_nodes` made them (a nodelet loader bound to its manager): the fleet is given them
        at the start and at each reload."""
        return relations_of((n.full_name, n.policy) for n in self.config.nodes if not self.remote(n))

    def check_nodes(self, required: bool) -> None:
        """The launch's nodes checked (a LaunchError naming the file and line), each nodelet loader bound to its
        manager; `required`: every node is required (`--required`)."""
        self.config = bind_nodelets(self.config, self.remote)  # (a loader bound to its manager may close a cycle)
        check_cycles(self.config.nodes)
        check_output_waits(self.config.nodes, self.remote)
        for node in self.config.nodes:
            if required and node.respawn:
                raise LaunchError("respawn and required cannot both be set to true (node [%s], --required)"
                                  % node.full_name, node.filename or None, node.line or None)
            if node.respawn and node.required:
                raise LaunchError("respawn and required cannot both be set to true (node [%s])" % node.full_name,
                                  node.filename or None, node.line or None)
        for node in self.config.nodes + self.config.tests:
            if node.machine_name and node.machine_name not in self.config.machines:
                # (roslaunch gives every node and test its machine before it runs anything, and refuses the launch
                # here; its --nodes, --args and --dump-params do not look)
                raise LaunchError("unknown machine [%s]: no <machine> tag declares it (%s [%s])" % (
                    node.machine_name, "test" if node.is_test else "node", node.full_name),
                    node.filename or None, node.line or None)
