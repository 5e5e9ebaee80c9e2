// The driver protocol (driver_protocol.h, driver_device.h) on every robot of models/: a state and a
// command written then read back through LCM's encoding give the same Pinocchio q, v, efforts and
// wrenches (the base converted to world axes and back), in any joint order; a state that does not
// fit the robot is refused naming what differs; reading allocates nothing once sized; the device
// refuses states that go back in order or time and counts the skipped ones.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <random>
#include <string>
#include <vector>

#include "allocation_counter.h"
#include "marionette/controller/driver_device.h"
#include "marionette/controller/driver_protocol.h"
#include "marionette/controller/robots.h"
#include "marionette/sot/kinematics.h"

namespace {

namespace mc = marionette::controller;
const std::string kModels = MARIONETTE_MODELS_DIR;

struct Robot {
  mc::RobotInfo info;
  marionette::sot::ModelPtr model;
  mc::DriverLayout layout;
};

Robot Load(const std::string& name) {
  Robot r;
  r.info = mc::FindRobot(name, kModels);
  r.model = marionette::sot::LoadModel(r.info.urdf, marionette::sot::ParseBaseJoint(r.info.base),
                                       r.info.srdf);
  r.layout = mc::MakeDriverLayout(*r.model, r.info);
  return r;
}

// A random state: q = neutral ⊕ random v (quaternions stay unit), random v, efforts, wrenches.
mc::MeasuredState RandomState(const Robot& r, std::mt19937* rng, int64_t sequence) {
  std::normal_distribution<double> n(0.0, 1.0);
  Eigen::VectorXd dq(r.model->nv);
  for (int i = 0; i < dq.size(); ++i) dq[i] = n(*rng);
  mc::MeasuredState s;
  s.q = pinocchio::integrate(*r.model, pinocchio::neutral(*r.model), dq);
  s.v = Eigen::VectorXd(r.model->nv);
  s.effort = Eigen::VectorXd::Zero(r.model->nv);
  for (int i = 0; i < s.v.size(); ++i) s.v[i] = n(*rng);
  for (int idx : r.layout.idx_v) s.effort[idx] = 10.0 * n(*rng);
  s.wrenches.resize(6 * r.layout.wrench_bodies.size());
  for (double& w : s.wrenches) w = 50.0 * n(*rng);
  s.sequence = sequence;
  s.utime = 1000 * sequence + 7;
  return s;
}

// What the wire carries: encode then decode.
template <typename Msg>
Msg ThroughWire(const Msg& msg) {
  std::vector<uint8_t> buffer(msg.getEncodedSize());
  EXPECT_EQ(msg.encode(buffer.data(), 0, static_cast<int>(buffer.size())),
            static_cast<int>(buffer.size()));
  Msg out;
  EXPECT_EQ(out.decode(buffer.data(), 0, static_cast<int>(buffer.size())),
            static_cast<int>(buffer.size()));
  return out;
}

// The base-only entries Read fills are those of the layout's base; every other entry of q, v is a
// joint's. Compared entry by entry, quaternion up to sign.
void ExpectSameState(const Robot& r, const mc::MeasuredState& a, const mc::MeasuredState& b) {
  ASSERT_EQ(a.q.size(), b.q.size());
  Eigen::VectorXd qa = a.q, qb = b.q;
  if (r.info.base == "free_flyer" && qa.segment<4>(3).dot(qb.segment<4>(3)) < 0.0)
    qb.segment<4>(3) *= -1.0;
  EXPECT_LT((qa - qb).cwiseAbs().maxCoeff(), 1e-12) << r.info.name;
  EXPECT_LT((a.v - b.v).cwiseAbs().maxCoeff(), 1e-12) << r.info.name;
  EXPECT_EQ(a.effort, b.effort) << r.info.name;
  EXPECT_EQ(a.wrenches, b.wrenches) << r.info.name;
  EXPECT_EQ(a.sequence, b.sequence);
  EXPECT_EQ(a.utime, b.utime);
}

// Reverses the order of the joints (and wrench bodies) of a state message.
void Reverse(marionette::lcmt_driver_state* m) {
  std::reverse(m->joint_name.begin(), m->joint_name.end());
  std::reverse(m->joint_position.begin(), m->joint_position.end());
  std::reverse(m->joint_velocity.begin(), m->joint_velocity.end());
  std::reverse(m->joint_effort.begin(), m->joint_effort.end());
  std::reverse(m->wrench_body.begin(), m->wrench_body.end());
  std::reverse(m->wrench.begin(), m->wrench.end());
}

class EveryRobot : public ::testing::TestWithParam<std::string> {};

TEST_P(EveryRobot, StateAndCommandSurviveTheWireInAnyJointOrder) {
  const Robot r = Load(GetParam());
  std::mt19937 rng(7);
  mc::StateReader reader(r.layout);
  for (int trial = 0; trial < 20; ++trial) {
    const mc::MeasuredState sent = RandomState(r, &rng, trial);
    marionette::lcmt_driver_state msg{};
    mc::WriteState(r.layout, sent, &msg);
    marionette::lcmt_driver_state received = ThroughWire(msg);
    if (trial % 2 == 1) Reverse(&received);
    mc::MeasuredState read;
    std::string why;
    ASSERT_TRUE(reader.Read(received, &read, &why)) << why;
    ExpectSameState(r, sent, read);
  }
  mc::JointCommand command;
  command.q = RandomState(r, &rng, 0).q;
  command.v = RandomState(r, &rng, 0).v;
  command.sequence = 41, command.utime = 41007, command.mode = 1;
  marionette::lcmt_driver_command msg{};
  mc::WriteCommand(r.layout, command, &msg);
  mc::CommandReader commands(r.layout);
  mc::JointCommand read;
  std::string why;
  ASSERT_TRUE(commands.Read(ThroughWire(msg), &read, &why)) << why;
  EXPECT_EQ(read.sequence, 41);
  EXPECT_EQ(read.utime, 41007);
  EXPECT_EQ(read.mode, 1);
  for (size_t i = 0; i < r.layout.joints.size(); ++i) {
    EXPECT_EQ(read.q[r.layout.idx_q[i]], command.q[r.layout.idx_q[i]]);
    EXPECT_EQ(read.v[r.layout.idx_v[i]], command.v[r.layout.idx_v[i]]);
  }
}

TEST_P(EveryRobot, ReadingAndWritingAllocateNothingOnceSized) {
  const Robot r = Load(GetParam());
  std::mt19937 rng(3);
  mc::StateReader reader(r.layout);
  const mc::MeasuredState sent = RandomState(r, &rng, 1);
  marionette::lcmt_driver_state msg{};
  mc::WriteState(r.layout, sent, &msg);
  mc::MeasuredState read;
  std::string why;
  ASSERT_TRUE(reader.Read(msg, &read, &why));
  mc::JointCommand command{0, 0, 0, sent.q, sent.v};
  marionette::lcmt_driver_command command_msg{};
  mc::WriteCommand(r.layout, command, &command_msg);
  marionette::testing::ScopedAllocationCounter counter;
  mc::WriteState(r.layout, sent, &msg);
  ASSERT_TRUE(reader.Read(msg, &read, &why));
  mc::WriteCommand(r.layout, command, &command_msg);
  EXPECT_EQ(counter.allocations(), 0);
}

TEST_P(EveryRobot, AStateThatDoesNotFitTheRobotIsRefusedNamingWhatDiffers) {
  const Robot r = Load(GetParam());
  std::mt19937 rng(5);
  marionette::lcmt_driver_state good{};
  mc::WriteState(r.layout, RandomState(r, &rng, 1), &good);
  const auto refused = [&](marionette::lcmt_driver_state m, const std::string& needle) {
    mc::StateReader reader(r.layout);
    mc::MeasuredState out;
    std::string why;
    EXPECT_FALSE(reader.Read(m, &out, &why)) << needle;
    EXPECT_NE(why.find(needle), std::string::npos) << "'" << why << "' lacks '" << needle << "'";
  };
  {
    marionette::lcmt_driver_state m = good;  // one joint fewer: the description's last
    m.num_joints -= 1;
    m.joint_name.pop_back(), m.joint_position.pop_back(), m.joint_velocity.pop_back();
    m.joint_effort.pop_back();
    refused(m, "'" + r.layout.joints.back() + "' is missing");
  }
  {
    marionette::lcmt_driver_state m = good;
    m.joint_name[0] = "no_such_joint";
    refused(m, "unknown joint 'no_such_joint'");
  }
  if (r.layout.joints.size() > 1) {
    marionette::lcmt_driver_state m = good;
    m.joint_name[1] = m.joint_name[0];
    refused(m, "given twice");
  }
  {
    marionette::lcmt_driver_state m = good;
    m.protocol_version = 2;
    refused(m, "protocol version 2");
  }
  {
    marionette::lcmt_driver_state m = good;
    m.has_base = !m.has_base;
    refused(m, "base");
  }
  if (r.info.base != "fixed") {
    marionette::lcmt_driver_state m = good;
    m.base_quaternion[0] *= 1.5;
    refused(m, "quaternion");
  }
}

INSTANTIATE_TEST_SUITE_P(Robots, EveryRobot,
                         ::testing::ValuesIn(mc::RobotNames(MARIONETTE_MODELS_DIR)),
                         [](const auto& info) { return info.param; });

// The device against the order and the clock of the states it is offered.
class DeviceTest : public ::testing::Test {
 protected:
  DeviceTest() : robot_(Load("ur10")), rng_(11) {}

  std::vector<uint8_t> Encode(int64_t sequence, int64_t utime, double position0 = 0.1) {
    mc::MeasuredState s = RandomState(robot_, &rng_, sequence);
    s.utime = utime;
    s.q[robot_.layout.idx_q[0]] = position0;
    marionette::lcmt_driver_state m{};
    mc::WriteState(robot_.layout, s, &m);
    std::vector<uint8_t> bytes(m.getEncodedSize());
    m.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
    return bytes;
  }
  bool Offer(const std::vector<uint8_t>& bytes, mc::DriverDevice::Refusal* why) {
    return device_->Offer(bytes.data(), bytes.size(), why);
  }
  void Start(int64_t sequence, int64_t utime) {
    const std::vector<uint8_t> first = Encode(sequence, utime);
    const mc::MeasuredState state =
        mc::ReadState(std::string(first.begin(), first.end()), robot_.layout);
    device_ = std::make_unique<mc::DriverDevice>("device", robot_.layout, state, nullptr,
                                                 /*max_clock_step_us=*/100000);
    mc::DriverDevice::Refusal why;
    ASSERT_TRUE(Offer(first, &why)) << why.detail;
  }

  Robot robot_;
  std::mt19937 rng_;
  std::unique_ptr<mc::DriverDevice> device_;
};

TEST_F(DeviceTest, StatesThatDoNotAdvanceAreRefusedAndSkippedOnesCounted) {
  Start(10, 10000);
  mc::DriverDevice::Refusal why;
  EXPECT_FALSE(Offer(Encode(10, 11000), &why));
  EXPECT_EQ(why.category, "duplicated");
  EXPECT_FALSE(Offer(Encode(9, 12000), &why));
  EXPECT_EQ(why.category, "out of order");
  EXPECT_FALSE(Offer(Encode(11, 10000), &why));
  EXPECT_EQ(why.category, "clock went back");
  EXPECT_TRUE(Offer(Encode(11, 11000), &why)) << why.detail;
  EXPECT_EQ(device_->missed_states(), 0);
  EXPECT_TRUE(Offer(Encode(14, 14000), &why)) << why.detail;  // 12 and 13 never came
  EXPECT_EQ(device_->missed_states(), 2);
  // A jump of the robot's clock: refused, and the clock goes on from there.
  EXPECT_FALSE(Offer(Encode(15, 14000 + 250000), &why));
  EXPECT_EQ(why.category, "clock jump");
  EXPECT_FALSE(device_->has_state());
  EXPECT_TRUE(Offer(Encode(16, 14000 + 251000), &why)) << why.detail;
}

TEST_F(DeviceTest, NonFiniteAndLyingMessagesAreRefusedByTheBounds) {
  Start(0, 1000);
  mc::DriverDevice::Refusal why;
  EXPECT_FALSE(Offer(Encode(1, 2000, std::numeric_limits<double>::quiet_NaN()), &why));
  EXPECT_EQ(why.category, "out of range") << why.detail;
  std::vector<uint8_t> bytes = Encode(2, 3000);
  bytes.resize(bytes.size() - 5);
  EXPECT_FALSE(Offer(bytes, &why));
  EXPECT_EQ(why.category, "past the end") << why.detail;
  bytes = Encode(3, 4000);
  bytes.push_back(0);
  EXPECT_FALSE(Offer(bytes, &why));
  EXPECT_EQ(why.category, "trailing bytes") << why.detail;
  EXPECT_TRUE(Offer(Encode(4, 5000), &why)) << why.detail;  // nothing was lost
}

}  // namespace
