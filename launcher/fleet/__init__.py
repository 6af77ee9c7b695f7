"""The nodes' state: the node state machine (`lifecycle`, a pure transition table), the launch's own phase
(`launchphase`), the relations among nodes (`relations`), the restart policy the node table applies
(`restart`), and the one home of every node's record that every view listens to (`state.Fleet`)."""
