"""Bags: rosbag's record, play, info and reindex, on rosbags and our TCPROS code (no ROS needed)."""
