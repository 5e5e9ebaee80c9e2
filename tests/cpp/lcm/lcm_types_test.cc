// Generated LCM types survive encode -> decode unchanged, and a truncated or corrupted
// buffer is refused by decode (the controller relies on that to reject garbage).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "marionette/lcm/channels.h"
#include "marionette/lcmt_camera_image.hpp"
#include "marionette/lcmt_controller_spec.hpp"
#include "marionette/lcmt_footstep_plan.hpp"
#include "marionette/lcmt_robot_state.hpp"
#include "marionette/lcmt_task_reference.hpp"

namespace marionette {
namespace {

template <typename Msg>
Msg RoundTrip(const Msg& in) {
  std::vector<uint8_t> buffer(in.getEncodedSize());
  EXPECT_EQ(in.encode(buffer.data(), 0, buffer.size()), static_cast<int>(buffer.size()));
  Msg out;
  EXPECT_EQ(out.decode(buffer.data(), 0, buffer.size()), static_cast<int>(buffer.size()));
  return out;
}

lcmt_robot_state MakeState() {
  lcmt_robot_state s;
  s.utime = 123456789;
  s.tick = 4242;
  s.robot_name = "talos";
  s.num_joints = 3;
  s.joint_name = {"a", "b", "c"};
  s.joint_position = {0.1, -0.2, M_PI};
  s.joint_velocity = {1.0, 2.0, 3.0};
  s.joint_effort = {-4.0, 5.5, 1e-9};
  for (int i = 0; i < 3; ++i) {
    s.base_position[i] = i + 0.5;
    s.base_linear_velocity[i] = -i;
    s.base_angular_velocity[i] = 2 * i;
  }
  s.base_quaternion[0] = 1.0;
  s.base_quaternion[1] = s.base_quaternion[2] = s.base_quaternion[3] = 0.0;
  s.num_contacts = 2;
  s.contact_frame = {"left_sole_link", "right_sole_link"};
  s.contact_wrench = {{1, 2, 3, 4, 5, 6}, {-1, -2, -3, -4, -5, -6}};
  return s;
}

TEST(LcmTypesTest, RobotStateRoundTrips) {
  const lcmt_robot_state in = MakeState();
  const lcmt_robot_state out = RoundTrip(in);
  EXPECT_EQ(out.utime, in.utime);
  EXPECT_EQ(out.tick, in.tick);
  EXPECT_EQ(out.robot_name, "talos");
  EXPECT_EQ(out.joint_name, in.joint_name);
  EXPECT_EQ(out.joint_position, in.joint_position);
  EXPECT_EQ(out.joint_effort, in.joint_effort);
  EXPECT_EQ(out.contact_wrench, in.contact_wrench);
  EXPECT_DOUBLE_EQ(out.base_position[2], 2.5);
}

TEST(LcmTypesTest, ControllerSpecWithNestedTasksRoundTrips) {
  lcmt_controller_spec in;
  in.utime = 7;
  in.controller_id = 3;
  in.name = "talos/left_gripper > plank/H1 | f_01";
  in.max_switch_velocity_jump = 0.05;
  in.reference_timeout = 0.1;
  in.num_tasks = 2;
  in.tasks.resize(2);
  in.tasks[0].name = "left_foot";
  in.tasks[0].kind = "se3";
  in.tasks[0].priority = 0;
  in.tasks[0].frame = "left_sole_link";
  for (int8_t& m : in.tasks[0].mask) m = 1;
  in.tasks[0].gain = 10.0;
  in.tasks[0].num_reference = 7;
  in.tasks[0].reference = {0, 0.1, 0, 1, 0, 0, 0};
  in.tasks[1].name = "posture";
  in.tasks[1].kind = "posture";
  in.tasks[1].priority = 2;
  in.tasks[1].num_joints = 2;
  in.tasks[1].joint_name = {"arm_left_1_joint", "arm_left_2_joint"};
  in.tasks[1].num_parameters = 1;
  in.tasks[1].parameter_name = {"force_target"};
  in.tasks[1].parameter_value = {5.0};
  const lcmt_controller_spec out = RoundTrip(in);
  ASSERT_EQ(out.num_tasks, 2);
  EXPECT_EQ(out.name, in.name);
  EXPECT_EQ(out.tasks[0].reference, in.tasks[0].reference);
  EXPECT_TRUE(out.tasks[0].mask[5]);
  EXPECT_EQ(out.tasks[1].joint_name, in.tasks[1].joint_name);
  EXPECT_EQ(out.tasks[1].parameter_value[0], 5.0);
}

TEST(LcmTypesTest, TaskReferenceTwoDimensionalArraysRoundTrip) {
  lcmt_task_reference in;
  in.utime = 1000;
  in.task_name = "right_gripper";
  in.controller_id = 1;
  in.dt_us = 1000;
  in.num_samples = 3;
  in.value_size = 7;
  in.derivative_size = 6;
  in.value.assign(3, std::vector<double>(7, 0.0));
  in.derivative.assign(3, std::vector<double>(6, 0.0));
  for (int i = 0; i < 3; ++i) {
    in.value[i][0] = 0.1 * i;
    in.value[i][3] = 1.0;
    in.derivative[i][5] = -0.5 * i;
  }
  in.last_chunk = true;
  in.sequence = 7;
  const lcmt_task_reference out = RoundTrip(in);
  EXPECT_EQ(out.value, in.value);
  EXPECT_EQ(out.derivative, in.derivative);
  EXPECT_TRUE(out.last_chunk);
  EXPECT_EQ(out.sequence, 7);
}

TEST(LcmTypesTest, CameraImageRoundTripsWithPixels) {
  lcmt_camera_image in;
  in.utime = 33000;
  in.camera_name = "head";
  in.frame_name = "rgbd_optical_frame";
  in.width = 4;
  in.height = 2;
  in.fx = in.fy = 500.0;
  in.cx = 2.0;
  in.cy = 1.0;
  in.depth_scale = 0.001;
  in.num_rgb = 4 * 2 * 3;
  in.rgb.resize(in.num_rgb);
  for (int i = 0; i < in.num_rgb; ++i) in.rgb[i] = static_cast<uint8_t>(i * 7);
  in.num_depth = 8;
  in.depth = {0, 1, 2, 3, 1000, 2000, 30000, -1};
  const lcmt_camera_image out = RoundTrip(in);
  EXPECT_EQ(out.rgb, in.rgb);
  EXPECT_EQ(out.depth, in.depth);
  EXPECT_EQ(out.fx, 500.0);
}

TEST(LcmTypesTest, FootstepPlanRoundTrips) {
  lcmt_footstep_plan in;
  in.utime = 5;
  in.plan_id = 9;
  in.first_step_index = 2;
  in.num_steps = 2;
  in.steps.resize(2);
  in.steps[0].is_left = true;
  in.steps[0].x = 0.2;
  in.steps[0].yaw = 0.1;
  in.steps[1].num_via = 1;
  in.steps[1].via = {{0.3, 0.0, 0.15}};
  in.stop_at_end = true;
  const lcmt_footstep_plan out = RoundTrip(in);
  EXPECT_TRUE(out.steps[0].is_left);
  EXPECT_DOUBLE_EQ(out.steps[0].x, 0.2);
  EXPECT_EQ(out.steps[1].via, in.steps[1].via);
}

TEST(LcmTypesTest, TruncatedBufferIsRefused) {
  const lcmt_robot_state in = MakeState();
  std::vector<uint8_t> buffer(in.getEncodedSize());
  in.encode(buffer.data(), 0, buffer.size());
  lcmt_robot_state out;
  EXPECT_LT(out.decode(buffer.data(), 0, buffer.size() / 2), 0);
}

TEST(LcmTypesTest, WrongTypeIsRefusedByFingerprint) {
  const lcmt_robot_state in = MakeState();
  std::vector<uint8_t> buffer(in.getEncodedSize());
  in.encode(buffer.data(), 0, buffer.size());
  lcmt_footstep_plan other;
  EXPECT_LT(other.decode(buffer.data(), 0, buffer.size()), 0);
}

}  // namespace
}  // namespace marionette
