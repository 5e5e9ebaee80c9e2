// lcm_publish_messages URL COUNT: publishes COUNT lcmt_robot_state messages on ROBOT_STATE
// (tick i, joint_position[j] = i + 0.25 j), 10 ms apart, for the C++ -> Python LCM test.
#include <lcm/lcm-cpp.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>

#include "marionette/lcm/channels.h"
#include "marionette/lcmt_robot_state.hpp"

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s LCM_URL COUNT\n", argv[0]);
    return 2;
  }
  lcm::LCM lcm(argv[1]);
  if (!lcm.good()) {
    std::fprintf(stderr, "cannot open LCM at %s\n", argv[1]);
    return 1;
  }
  const int count = std::atoi(argv[2]);
  for (int i = 0; i < count; ++i) {
    marionette::lcmt_robot_state s{};
    s.utime = 1000 * i;
    s.tick = i;
    s.robot_name = "cpp-publisher";
    s.num_joints = 4;
    for (int j = 0; j < 4; ++j) {
      s.joint_name.push_back("joint_" + std::to_string(j));
      s.joint_position.push_back(i + 0.25 * j);
      s.joint_velocity.push_back(-j);
      s.joint_effort.push_back(0.0);
    }
    s.base_quaternion[0] = 1.0;
    s.num_contacts = 0;
    lcm.publish(marionette::channels::kRobotState, &s);
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return 0;
}
