#pragma once
/// What the controller knows of each robot: files, base, reference posture, the bodies whose
/// contact wrenches it measures, its camera, its grippers. The same facts as
/// python/marionette/robots.py and models/<robot>/grippers.yaml;
/// tests/python/controller/test_robots_agree.py checks both sides agree
/// (`marionette-controller --describe-robot NAME` prints this as JSON).

#include <string>
#include <vector>

namespace marionette::controller {

struct GripperInfo {
  std::string name;   ///< e.g. "talos/left_gripper"
  std::string joint;  ///< the actuated gripper joint
  double open_position = 0.0;
  double closed_position = 0.0;
};

struct RobotInfo {
  std::string name;
  std::string urdf;                         ///< absolute path
  std::string srdf;                         ///< absolute path
  std::string mjcf;                         ///< the robot alone (the default scene)
  std::string base;                         ///< "free_flyer" | "planar" | "fixed"
  std::string reference;                    ///< SRDF group_state of the initial posture
  std::vector<std::string> contact_bodies;  ///< wrenches measured on these (soles)
  /// Gripper finger bodies whose contact wrenches (MuJoCo contact forces) are measured and
  /// published after the soles' in ROBOT_STATE: the grip force an admittance task holds, seen
  /// independently of its motor-current estimate (issue 7). Not soles: no balance or ZMP use.
  std::vector<std::string> grip_bodies;
  /// contact_bodies then grip_bodies: the bodies MujocoDevice measures, in ROBOT_STATE's order.
  std::vector<std::string> measured_bodies() const {
    std::vector<std::string> out = contact_bodies;
    out.insert(out.end(), grip_bodies.begin(), grip_bodies.end());
    return out;
  }
  std::string camera;        ///< MuJoCo camera name, "" if none
  std::string camera_frame;  ///< Pinocchio frame of the camera's optical centre, "" if none
  std::vector<GripperInfo> grippers;
};

/// The robots marionette knows.
std::vector<std::string> RobotNames();
/// The description of `name` with paths under `models_dir`; throws std::invalid_argument
/// listing the known robots.
RobotInfo FindRobot(const std::string& name, const std::string& models_dir);
/// JSON of a RobotInfo (for the agreement test and users).
/// The base velocities every controller holds at zero (ControllerFactory's held_velocities): a
/// planar base's three (TIAGo's wheels are not simulated: the MuJoCo device commands 1-DoF
/// joints only and the scene holds the base; a differential drive could not follow a sideways
/// velocity anyway); none for a free flyer (it moves through the contacts) or a fixed base.
std::vector<int> HeldBaseVelocities(const RobotInfo& robot);

std::string ToJson(const RobotInfo& robot);

}  // namespace marionette::controller
