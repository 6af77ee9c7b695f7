"""`python -m launcher.bag record|play|info|reindex ...`: what a launch file's rosbag node runs without ROS."""

import sys

from launcher.bag.main import main

sys.exit(main())
