"""The operator's client side of a running launch: `launcher status/start/stop/restart/logs/events`, the last run read from its log directory, the live view (terminal and web), `launcher install`."""
