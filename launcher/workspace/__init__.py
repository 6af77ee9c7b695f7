"""The machine's ROS workspace: ROS_HOME and the log root, packages and executables (the crawl and its cache), the python a node script runs."""
