"""Health watchers of running nodes: readiness (wait_for), hang (getPid probes), stalled topics, CPU and memory limits. Each tells the fleet what it saw."""
