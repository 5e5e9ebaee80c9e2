#pragma once
/// The joint-level driver protocol (docs/driver.md) in Pinocchio's layout: how a robot's measured
/// state and the controller's command travel in lcmt_driver_state / lcmt_driver_command, and
/// which messages do not fit the robot. Written once, read by both ends: the controller's
/// DriverDevice (driver_device.h) and marionette-sim, the simulator as a driver.
///
/// Joints travel by name, in any order; a reader remembers the order of the last message, so a
/// driver that keeps its order costs one string comparison per joint and no allocation. The
/// floating base travels in world axes (p_WB, R_WB as w x y z, v_WB, w_WB) and is converted to
/// Pinocchio's (x y z qx qy qz qw; linear and angular velocity in the base frame) or, for a planar
/// base, (x y cos sin; vx vy in the base frame, wz).

#include <Eigen/Core>
#include <cstdint>
#include <pinocchio/multibody/model.hpp>
#include <string>
#include <vector>

#include "marionette/controller/robots.h"
#include "marionette/lcmt_driver_command.hpp"
#include "marionette/lcmt_driver_state.hpp"

namespace marionette::controller {

inline constexpr int16_t kDriverProtocolVersion = 1;

/// Where a robot's measured quantities live in Pinocchio's q (nq) and v (nv).
struct DriverLayout {
  std::string robot_name;
  std::vector<std::string> joints;         ///< every 1-dof joint, in Pinocchio order
  std::vector<int> idx_q, idx_v;           ///< their indices in q and v
  std::string base;                        ///< "fixed" | "free_flyer" | "planar"
  std::vector<std::string> wrench_bodies;  ///< robot.measured_bodies(): soles, then fingers
  int nq = 0, nv = 0;
};

/// The layout of `model`, loaded from `robot` (its URDF, base and SRDF).
DriverLayout MakeDriverLayout(const pinocchio::Model& model, const RobotInfo& robot);
/// "a, b, c": the joints a driver must name (for messages and logs).
std::string JointList(const DriverLayout& layout);

/// A robot's measured state in Pinocchio's layout.
struct MeasuredState {
  int64_t utime = 0;             ///< the robot's clock [us]
  int64_t sequence = 0;          ///< the driver's cycle count
  Eigen::VectorXd q, v, effort;  ///< (nq), (nv), (nv; 0 on the base)
  std::vector<double> wrenches;  ///< 6 per layout.wrench_bodies: (f, tau) world axes [N, N m]
};

/// The command for one state: joint targets in Pinocchio's layout (the base entries unused).
struct JointCommand {
  int64_t utime = 0;     ///< of the state it answers
  int64_t sequence = 0;  ///< of the state it answers
  int8_t mode = 0;       ///< 0 track, 1 hold
  Eigen::VectorXd q, v;  ///< (nq), (nv)
};

/// Maps a message's joint (and wrench body) order onto the layout; remembers the last order.
class NameOrder {
 public:
  /// The layout's index of each of `names` (size = names.size()), or false with `why` naming the
  /// first missing, unknown or repeated name. No allocation when the order did not change.
  bool Match(const std::vector<std::string>& expected, const std::vector<std::string>& names,
             const char* what, std::string* why);
  const std::vector<int>& order() const { return order_; }

 private:
  std::vector<std::string> last_;  // the names of the last message that matched
  std::vector<int> order_;         // message index -> layout index
};

/// Reads DRIVER_STATE messages against one layout.
class StateReader {
 public:
  explicit StateReader(DriverLayout layout);
  /// True and `out` filled (sized once) when `msg` fits the layout: the protocol version, the
  /// robot's exact joints, a base exactly when the robot floats (unit quaternion), the wrench
  /// bodies. Else false and `why`: one line saying what differs and what to send.
  bool Read(const lcmt_driver_state& msg, MeasuredState* out, std::string* why);
  const DriverLayout& layout() const { return layout_; }

 private:
  DriverLayout layout_;
  NameOrder joints_, wrenches_;
};

/// Fills `msg` from a state (sizes it on the first call, no allocation after).
void WriteState(const DriverLayout& layout, const MeasuredState& state, lcmt_driver_state* msg);

/// Reads DRIVER_COMMAND messages against one layout (the driver's side).
class CommandReader {
 public:
  explicit CommandReader(DriverLayout layout);
  /// True and `out` filled when `msg` names the robot's exact joints with the protocol's version.
  bool Read(const lcmt_driver_command& msg, JointCommand* out, std::string* why);

 private:
  DriverLayout layout_;
  NameOrder joints_;
};

/// Fills `msg` from a command (sizes it on the first call, no allocation after).
void WriteCommand(const DriverLayout& layout, const JointCommand& command,
                  lcmt_driver_command* msg);

}  // namespace marionette::controller
