"""Parameters: value typing, ROS YAML load/dump, and the parameter tree (import-free package)."""
