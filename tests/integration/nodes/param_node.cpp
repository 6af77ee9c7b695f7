// Real roscpp node for the launch tests: at start-up, reads its parameters and writes what it saw to
// the file named by ~out; then spins until SIGINT.
#include <ros/ros.h>
#include <fstream>
#include <string>

int main(int argc, char** argv) {
  ros::init(argc, argv, "param_node");
  ros::NodeHandle pnh("~");
  std::string out, priv, glob;
  pnh.getParam("out", out);
  bool has_priv = pnh.getParam("value", priv);
  bool has_glob = ros::param::get("/shared/value", glob);
  bool has_stale = ros::param::has(ros::this_node::getName() + "/stale");
  std::ofstream f((out + ".tmp").c_str());
  f << "private=" << (has_priv ? priv : "<unset>") << "\n"
    << "global=" << (has_glob ? glob : "<unset>") << "\n"
    << "stale=" << (has_stale ? "present" : "absent") << "\n";
  f.close();
  std::rename((out + ".tmp").c_str(), out.c_str());
  ros::spin();
  return 0;
}
