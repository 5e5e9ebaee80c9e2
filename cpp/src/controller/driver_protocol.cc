// The driver protocol in Pinocchio's layout (driver_protocol.h).
#include "marionette/controller/driver_protocol.h"

#include <Eigen/Geometry>
#include <cmath>

namespace marionette::controller {

DriverLayout MakeDriverLayout(const pinocchio::Model& model, const RobotInfo& robot) {
  DriverLayout layout;
  layout.robot_name = robot.name;
  layout.base = robot.base;
  layout.wrench_bodies = robot.measured_bodies();
  layout.nq = model.nq;
  layout.nv = model.nv;
  for (pinocchio::JointIndex j = 1; j < model.joints.size(); ++j) {
    if (model.joints[j].nq() == 1 && model.joints[j].nv() == 1) {
      layout.joints.push_back(model.names[j]);
      layout.idx_q.push_back(model.joints[j].idx_q());
      layout.idx_v.push_back(model.joints[j].idx_v());
    }
  }
  return layout;
}

std::string JointList(const DriverLayout& layout) {
  std::string out;
  for (const std::string& j : layout.joints) out += (out.empty() ? "" : ", ") + j;
  return out;
}

bool NameOrder::Match(const std::vector<std::string>& expected,
                      const std::vector<std::string>& names, const char* what, std::string* why) {
  if (names == last_ && !last_.empty()) return true;  // the usual case: the order of last time
  if (expected.empty() && names.empty()) return true;
  std::vector<int> order(names.size(), -1);
  std::vector<bool> seen(expected.size(), false);
  for (size_t i = 0; i < names.size(); ++i) {
    int found = -1;
    for (size_t k = 0; k < expected.size() && found < 0; ++k)
      if (expected[k] == names[i]) found = static_cast<int>(k);
    if (found < 0) {
      *why = std::string("unknown ") + what + " '" + names[i] + "'";
      return false;
    }
    if (seen[found]) {
      *why = std::string(what) + " '" + names[i] + "' given twice";
      return false;
    }
    seen[found] = true;
    order[i] = found;
  }
  for (size_t k = 0; k < expected.size(); ++k) {
    if (!seen[k]) {
      *why = std::string(what) + " '" + expected[k] + "' is missing (" +
             std::to_string(names.size()) + " given, the robot has " +
             std::to_string(expected.size()) + ")";
      return false;
    }
  }
  last_ = names;
  order_ = std::move(order);
  return true;
}

StateReader::StateReader(DriverLayout layout) : layout_(std::move(layout)) {}

bool StateReader::Read(const lcmt_driver_state& msg, MeasuredState* out, std::string* why) {
  if (msg.protocol_version != kDriverProtocolVersion) {
    *why = "protocol version " + std::to_string(msg.protocol_version) +
           ", this controller speaks " + std::to_string(kDriverProtocolVersion);
    return false;
  }
  if (!joints_.Match(layout_.joints, msg.joint_name, "joint", why)) {
    *why += " (send exactly: " + JointList(layout_) + ")";
    return false;
  }
  if (!wrenches_.Match(layout_.wrench_bodies, msg.wrench_body, "wrench body", why)) {
    std::string bodies;
    for (const std::string& b : layout_.wrench_bodies) bodies += (bodies.empty() ? "" : ", ") + b;
    *why += " (send the wrench on each of: " + (bodies.empty() ? "none" : bodies) +
            "; zeros for a body the robot does not sense)";
    return false;
  }
  const bool floating = layout_.base != "fixed";
  if (msg.has_base != floating) {
    *why = floating ? "no base pose, and " + layout_.robot_name + " has a " + layout_.base +
                          " base (has_base true, from the robot's estimator)"
                    : layout_.robot_name + " is fixed-base and the state has a base pose";
    return false;
  }
  const Eigen::Quaterniond quat(msg.base_quaternion[0], msg.base_quaternion[1],
                                msg.base_quaternion[2], msg.base_quaternion[3]);
  if (floating && std::abs(quat.norm() - 1.0) > 1e-6) {
    *why =
        "base quaternion of norm " + std::to_string(quat.norm()) + " (a unit quaternion w x y z)";
    return false;
  }
  if (out->q.size() != layout_.nq) {
    out->q = Eigen::VectorXd::Zero(layout_.nq);
    out->v = Eigen::VectorXd::Zero(layout_.nv);
    out->effort = Eigen::VectorXd::Zero(layout_.nv);
    out->wrenches.assign(6 * layout_.wrench_bodies.size(), 0.0);
  }
  out->utime = msg.utime;
  out->sequence = msg.sequence;
  const std::vector<int>& order = joints_.order();
  for (size_t i = 0; i < order.size(); ++i) {
    out->q[layout_.idx_q[order[i]]] = msg.joint_position[i];
    out->v[layout_.idx_v[order[i]]] = msg.joint_velocity[i];
    out->effort[layout_.idx_v[order[i]]] = msg.joint_effort[i];
  }
  const std::vector<int>& bodies = wrenches_.order();
  for (size_t i = 0; i < bodies.size(); ++i)
    for (int k = 0; k < 6; ++k) out->wrenches[6 * bodies[i] + k] = msg.wrench[i][k];
  const Eigen::Map<const Eigen::Vector3d> p(msg.base_position), v_world(msg.base_linear_velocity),
      w_world(msg.base_angular_velocity);
  if (layout_.base == "free_flyer") {
    const Eigen::Matrix3d R = quat.toRotationMatrix();
    out->q.head<3>() = p;
    out->q.segment<4>(3) << quat.x(), quat.y(), quat.z(), quat.w();
    out->v.head<3>() = R.transpose() * v_world;
    out->v.segment<3>(3) = R.transpose() * w_world;
  } else if (layout_.base == "planar") {
    const double yaw = 2.0 * std::atan2(quat.z(), quat.w());
    const double c = std::cos(yaw), s = std::sin(yaw);
    out->q.head<4>() << p[0], p[1], c, s;
    out->v.head<3>() << c * v_world[0] + s * v_world[1], -s * v_world[0] + c * v_world[1],
        w_world[2];
  }
  return true;
}

void WriteState(const DriverLayout& layout, const MeasuredState& state, lcmt_driver_state* msg) {
  const int n = static_cast<int>(layout.joints.size());
  const int nw = static_cast<int>(layout.wrench_bodies.size());
  if (msg->num_joints != n || msg->joint_name.size() != static_cast<size_t>(n)) {
    msg->robot_name = layout.robot_name;
    msg->num_joints = n;
    msg->joint_name = layout.joints;
    msg->joint_position.assign(n, 0.0);
    msg->joint_velocity.assign(n, 0.0);
    msg->joint_effort.assign(n, 0.0);
    msg->num_wrenches = nw;
    msg->wrench_body = layout.wrench_bodies;
    msg->wrench.assign(nw, std::vector<double>(6, 0.0));
  }
  msg->protocol_version = kDriverProtocolVersion;
  msg->utime = state.utime;
  msg->sequence = state.sequence;
  for (int i = 0; i < n; ++i) {
    msg->joint_position[i] = state.q[layout.idx_q[i]];
    msg->joint_velocity[i] = state.v[layout.idx_v[i]];
    msg->joint_effort[i] = state.effort[layout.idx_v[i]];
  }
  for (int i = 0; i < nw; ++i)
    for (int k = 0; k < 6; ++k) msg->wrench[i][k] = state.wrenches[6 * i + k];
  msg->has_base = layout.base != "fixed";
  for (int k = 0; k < 3; ++k) {
    msg->base_position[k] = 0.0;
    msg->base_linear_velocity[k] = 0.0;
    msg->base_angular_velocity[k] = 0.0;
  }
  msg->base_quaternion[0] = 1.0;
  msg->base_quaternion[1] = msg->base_quaternion[2] = msg->base_quaternion[3] = 0.0;
  if (layout.base == "free_flyer") {
    const Eigen::Quaterniond quat(state.q[6], state.q[3], state.q[4], state.q[5]);
    const Eigen::Matrix3d R = quat.toRotationMatrix();
    const Eigen::Vector3d v_world = R * state.v.head<3>(), w_world = R * state.v.segment<3>(3);
    for (int k = 0; k < 3; ++k) {
      msg->base_position[k] = state.q[k];
      msg->base_linear_velocity[k] = v_world[k];
      msg->base_angular_velocity[k] = w_world[k];
    }
    msg->base_quaternion[0] = quat.w(), msg->base_quaternion[1] = quat.x();
    msg->base_quaternion[2] = quat.y(), msg->base_quaternion[3] = quat.z();
  } else if (layout.base == "planar") {
    const double yaw = std::atan2(state.q[3], state.q[2]);
    msg->base_position[0] = state.q[0], msg->base_position[1] = state.q[1];
    msg->base_quaternion[0] = std::cos(yaw / 2), msg->base_quaternion[3] = std::sin(yaw / 2);
    msg->base_linear_velocity[0] = std::cos(yaw) * state.v[0] - std::sin(yaw) * state.v[1];
    msg->base_linear_velocity[1] = std::sin(yaw) * state.v[0] + std::cos(yaw) * state.v[1];
    msg->base_angular_velocity[2] = state.v[2];
  }
}

CommandReader::CommandReader(DriverLayout layout) : layout_(std::move(layout)) {}

bool CommandReader::Read(const lcmt_driver_command& msg, JointCommand* out, std::string* why) {
  if (msg.protocol_version != kDriverProtocolVersion) {
    *why = "protocol version " + std::to_string(msg.protocol_version) + ", this driver speaks " +
           std::to_string(kDriverProtocolVersion);
    return false;
  }
  if (!joints_.Match(layout_.joints, msg.joint_name, "joint", why)) {
    *why += " (this robot's joints: " + JointList(layout_) + ")";
    return false;
  }
  if (out->q.size() != layout_.nq) {
    out->q = Eigen::VectorXd::Zero(layout_.nq);
    out->v = Eigen::VectorXd::Zero(layout_.nv);
  }
  out->utime = msg.utime;
  out->sequence = msg.sequence;
  out->mode = msg.mode;
  const std::vector<int>& order = joints_.order();
  for (size_t i = 0; i < order.size(); ++i) {
    out->q[layout_.idx_q[order[i]]] = msg.joint_position[i];
    out->v[layout_.idx_v[order[i]]] = msg.joint_velocity[i];
  }
  return true;
}

void WriteCommand(const DriverLayout& layout, const JointCommand& command,
                  lcmt_driver_command* msg) {
  const int n = static_cast<int>(layout.joints.size());
  if (msg->num_joints != n || msg->joint_name.size() != static_cast<size_t>(n)) {
    msg->num_joints = n;
    msg->joint_name = layout.joints;
    msg->joint_position.assign(n, 0.0);
    msg->joint_velocity.assign(n, 0.0);
    msg->joint_effort.assign(n, 0.0);
  }
  msg->protocol_version = kDriverProtocolVersion;
  msg->utime = command.utime;
  msg->sequence = command.sequence;
  msg->mode = command.mode;
  for (int i = 0; i < n; ++i) {
    msg->joint_position[i] = command.q[layout.idx_q[i]];
    msg->joint_velocity[i] = command.v[layout.idx_v[i]];
  }
}

}  // namespace marionette::controller
