#pragma once
/// What the controller knows of a robot, read from the robot's `robot.yaml` (the one description
/// Python reads too, python/marionette/robots.py; format: python/marionette/schemas/
/// robot.schema.json; guide: docs/robots.md). tests/python/controller/test_robots_agree.py
/// checks that `marionette-controller --describe-robot R` equals what Python loads, for every
/// robot found.

#include <string>
#include <vector>

namespace marionette::controller {

struct GripperInfo {
  std::string name;   ///< "<robot>/<gripper>"
  std::string joint;  ///< the actuated finger joint (grippers without one are not listed)
  double open_position = 0.0;
  double closed_position = 0.0;
};

struct RobotInfo {
  std::string name;
  std::string directory;                    ///< absolute path of the robot's folder
  std::string urdf;                         ///< absolute path
  std::string srdf;                         ///< absolute path
  std::string mjcf;                         ///< the robot alone (the default scene)
  std::string base;                         ///< "free_flyer" | "planar" | "fixed"
  std::string reference;                    ///< SRDF group_state of the initial posture
  std::vector<std::string> contact_bodies;  ///< wrenches measured on these (the feet's soles)
  /// Gripper finger bodies whose contact wrenches (MuJoCo contact forces) are measured and
  /// published after the soles' in ROBOT_STATE: the grip force an admittance task holds, seen
  /// independently of its motor-current estimate. Not soles: no balance or ZMP use.
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

/// Folders searched for robots: `models_dir`, then those of $MARIONETTE_ROBOT_PATH (':'-separated).
/// Each is a robot folder itself (it holds robot.yaml) or holds robot folders.
std::vector<std::string> RobotSearchPath(const std::string& models_dir);
/// Names of the robots found on the search path, sorted.
std::vector<std::string> RobotNames(const std::string& models_dir);
/// The robot `name_or_folder` (a name found on the search path, or a folder holding robot.yaml)
/// read from its robot.yaml; throws std::invalid_argument with a one-line reason (unknown name
/// with the known ones, unreadable file, missing or mistyped key with its path).
RobotInfo FindRobot(const std::string& name_or_folder, const std::string& models_dir);
/// The base velocities every controller holds at zero (ControllerFactory's held_velocities): a
/// planar base's three (a mobile base's wheels are not simulated: the MuJoCo device commands
/// 1-DoF joints only and the scene holds the base; a differential drive could not follow a
/// sideways velocity anyway); none for a free flyer (it moves through the contacts) or a fixed
/// base.
std::vector<int> HeldBaseVelocities(const RobotInfo& robot);
/// JSON of a RobotInfo (for the agreement test and users).
std::string ToJson(const RobotInfo& robot);

}  // namespace marionette::controller
