"""Node processes: spawning, watching, respawn, required, stop escalation, log directory."""
