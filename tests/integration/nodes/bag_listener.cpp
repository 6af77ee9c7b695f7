// Real roscpp subscriber for the bag tests: prints each std_msgs/String received on `topic`, one a line.
#include <ros/ros.h>
#include <std_msgs/String.h>
#include <cstdio>

static void on(const std_msgs::String::ConstPtr& msg) {
  std::printf("%s\n", msg->data.c_str());
  std::fflush(stdout);
}

int main(int argc, char** argv) {
  ros::init(argc, argv, "bag_listener", ros::init_options::AnonymousName);
  if (argc < 2) return 2;
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe(argv[1], 1000, on);
  ros::spin();
  return 0;
}
