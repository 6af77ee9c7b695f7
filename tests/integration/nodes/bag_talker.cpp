// Real roscpp publisher for the bag tests: once `subs` subscribers are connected, publishes
// std_msgs/String "<prefix> N" for N = 0..count-1 at `rate` Hz on `topic` (count 0: until SIGINT).
// argv: topic prefix count rate subs [pad]: with pad, each message is padded with 'x' to pad bytes;
// "done" on stdout once the last is published (the benchmark waits for it).
#include <ros/ros.h>
#include <std_msgs/String.h>
#include <cstdio>
#include <cstdlib>
#include <string>

int main(int argc, char** argv) {
  ros::init(argc, argv, "bag_talker", ros::init_options::AnonymousName);
  if (argc < 6) return 2;
  ros::NodeHandle nh;
  ros::Publisher pub = nh.advertise<std_msgs::String>(argv[1], 1000);
  std::string prefix = argv[2];
  int count = std::atoi(argv[3]);
  ros::Rate rate(std::atof(argv[4]));
  unsigned subs = std::atoi(argv[5]);
  size_t pad = argc > 6 ? std::atol(argv[6]) : 0;
  while (ros::ok() && pub.getNumSubscribers() < subs) ros::Duration(0.01).sleep();
  for (int n = 0; ros::ok() && (count == 0 || n < count); ++n) {
    std_msgs::String msg;
    msg.data = prefix + " " + std::to_string(n);
    if (msg.data.size() < pad) msg.data.resize(pad, 'x');
    pub.publish(msg);
    rate.sleep();
  }
  std::printf("done\n");
  std::fflush(stdout);
  ros::spin();
  return 0;
}
