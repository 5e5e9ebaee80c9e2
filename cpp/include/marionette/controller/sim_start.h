#pragma once
/// How a simulated run starts: the robot's start posture and the MuJoCo scene put in its first
/// state. One function for both simulators: marionette-controller's mujoco backend and
/// marionette-sim (the scene as a driver process), so that a split run starts where an in-process
/// run does.

#include <Eigen/Core>
#include <memory>
#include <pinocchio/multibody/model.hpp>
#include <string>
#include <utility>
#include <vector>

#include "marionette/controller/robots.h"
#include "marionette/lcmt_object_poses.hpp"
#include "marionette/sim/mujoco_scene.h"

namespace marionette::controller {

/// The SRDF group_state `robot.reference` with every gripper open (just inside its limit, as
/// marionette.robots does). Throws std::runtime_error when the SRDF has no such group_state.
Eigen::VectorXd ReferencePosture(const pinocchio::Model& model, const RobotInfo& robot);

/// A MuJoCo scene in its first state and what the simulator knows of its objects.
struct StartedScene {
  std::unique_ptr<sim::MujocoScene> scene;
  Eigen::VectorXd q0;                     ///< the robot's start configuration (Pinocchio, nq)
  std::vector<std::string> free_objects;  ///< bodies with a free joint, not the robot's base
  std::vector<int> free_object_ids;       ///< their MuJoCo body ids
};

/// Loads `mjcf_path` for `model` (mapped by joint names), applies the encoder offsets, and puts
/// it in its first state: the scene's first keyframe if it has one (scenes put the robot and the
/// objects in place), else `reference` (ReferencePosture) with the floating base where the model
/// file puts it, at rest. Throws std::runtime_error with MuJoCo's or the mapping's reason.
StartedScene StartScene(const std::string& mjcf_path, const pinocchio::Model& model,
                        const RobotInfo& robot, const Eigen::VectorXd& reference,
                        const std::vector<std::pair<std::string, double>>& encoder_offsets);

/// SIM_OBJECT_POSES (the simulator's ground truth, camera_name "simulator") at robot time `utime`
/// [us]: `names` with their poses, 7 per object in `poses` (x y z qw qx qy qz, world).
lcmt_object_poses SimulatorObjectPoses(const std::vector<std::string>& names,
                                       const std::vector<double>& poses, int64_t utime);

}  // namespace marionette::controller
