// Real roscpp subscriber for the bag tests: prints each std_msgs/String received on `topic`, one a line
// (argv: topic [stamp]: with "stamp", each line is the wall time of its arrival, for play's timing).
#include <ros/ros.h>
#include <std_msgs/String.h>
#include <cstdio>
#include <string>

static bool stamp = false;

static void on(const std_msgs::String::ConstPtr& msg) {
  if (stamp) std::printf("%.9f\n", ros::WallTime::now().toSec());
  else std::printf("%s\n", msg->data.c_str());
  std::fflush(stdout);
}

int main(int argc, char** argv) {
  ros::init(argc, argv, "bag_listener", ros::init_options::AnonymousName);
  if (argc < 2) return 2;
  stamp = argc > 2 && std::string(argv[2]) == "stamp";
  ros::NodeHandle nh;
  ros::Subscriber sub = nh.subscribe(argv[1], 1000, on);
  ros::spin();
  return 0;
}
