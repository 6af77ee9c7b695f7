"""The local runner of node processes: spawning, process groups and exits (pidfd), stop escalation, orphans reaped, core dumps, the no-orphans watchdog."""
