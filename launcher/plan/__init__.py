"""The plan: the step from a loaded `LaunchConfig` to what is executed (each local node's process spec, which machines are other hosts).

Worked out once per launch, before any socket or process: `plan` holds what
a run runs (`Plan`, pure), `machines` says which of the launch's machines are
this one, `specs` turns each node into the `ProcessSpec` a runner starts, `relations`
says who is bound to whom and who waits for whom. Reload's difference of two
plans belongs here too.
"""
