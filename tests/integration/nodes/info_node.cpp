// Real roscpp node for the screen output tests: ROS_INFO "tick N" five times a second until SIGINT.
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "info_node");
  ros::NodeHandle nh;
  ros::Rate rate(5);
  for (int n = 1; ros::ok(); ++n) {
    ROS_INFO("tick %d", n);
    rate.sleep();
  }
  return 0;
}
