// A roscpp gtest node for `launcher test`: two cases pass, one fails.
#include <gtest/gtest.h>
#include <ros/ros.h>

TEST(Sample, adds) { EXPECT_EQ(2, 1 + 1); }
TEST(Sample, fails) { EXPECT_EQ(3, 1 + 1) << "one and one are not three"; }
TEST(Sample, seesMaster) { EXPECT_TRUE(ros::master::check()); }

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "gtest_node");
  return RUN_ALL_TESTS();
}
