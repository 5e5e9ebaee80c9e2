#pragma once
/// How a simulated run starts: the robot's start posture and the MuJoCo scene put in its first
/// state. One function for both simulators: marionette-controller's mujoco backend and
/// marionette-sim (the scene as a driver process), so that a split run starts where an in-process
/// run does.

#include <Eigen/Core>
#include <memory>
#include <pinocchio/multibody/model.hpp>
#include <random>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "marionette/controller/robots.h"
#include "marionette/lcmt_object_poses.hpp"
#include "marionette/lcmt_range_finders.hpp"
#include "marionette/lcmt_sim_command.hpp"
#include "marionette/sim/mujoco_scene.h"

namespace marionette::controller {

/// The SRDF group_state `robot.reference` with every gripper open (just inside its limit, as
/// marionette.robots does). Throws std::runtime_error when the SRDF has no such group_state.
Eigen::VectorXd ReferencePosture(const pinocchio::Model& model, const RobotInfo& robot);

/// A scene's rangefinder sensors (each the distance along its site's +z to the first geom, -1
/// when none), in the model's order.
struct RangeFinderSet {
  std::vector<std::string> names;
  std::vector<int> adr;       ///< their addresses in mjData::sensordata
  std::vector<double> noise;  ///< their MJCF `noise`: 1 sigma [m]
  bool empty() const { return names.empty(); }
  size_t size() const { return names.size(); }
};

/// A MuJoCo scene in its first state and what the simulator knows of its objects.
struct StartedScene {
  std::unique_ptr<sim::MujocoScene> scene;
  Eigen::VectorXd q0;                     ///< the robot's start configuration (Pinocchio, nq)
  std::vector<std::string> free_objects;  ///< bodies with a free joint, not the robot's base
  std::vector<int> free_object_ids;       ///< their MuJoCo body ids
  RangeFinderSet range_finders;           ///< the scene's rangefinder sensors
};

/// Reads `range_finders` from `d` into `distances` (sized to them), each with the Gaussian noise of
/// its sensor's MJCF `noise` attribute (the standard deviation MuJoCo declares and leaves to its
/// user: a simulated sensor adds it here) drawn from `rng`; a beam that hit nothing stays -1. No
/// allocation.
void ReadRangeFinders(const RangeFinderSet& range_finders, const mjData& d, std::mt19937_64* rng,
                      std::vector<double>* distances);

/// Range finders one lcmt_range_finders carries (its `num_sensors`' @max).
inline constexpr int kMaxRangeFinders = 64;

/// Loads `mjcf_path` for `model` (mapped by joint names), applies the encoder offsets, and puts
/// it in its first state: the scene's first keyframe if it has one (scenes put the robot and the
/// objects in place), else `reference` (ReferencePosture) with the floating base where the model
/// file puts it, at rest. Throws std::runtime_error with MuJoCo's or the mapping's reason, or
/// when the scene has range finders that MuJoCo would not compute (sensors disabled) or more
/// than kMaxRangeFinders.
StartedScene StartScene(const std::string& mjcf_path, const pinocchio::Model& model,
                        const RobotInfo& robot, const Eigen::VectorXd& reference,
                        const std::vector<std::pair<std::string, double>>& encoder_offsets);

/// SIM_OBJECT_POSES (the simulator's ground truth, camera_name "simulator") at robot time `utime`
/// [us]: `names` with their poses, 7 per object in `poses` (x y z qw qx qy qz, world).
lcmt_object_poses SimulatorObjectPoses(const std::vector<std::string>& names,
                                       const std::vector<double>& poses, int64_t utime);

/// RANGE_FINDERS of robot `robot_name` at robot time `utime` [us]: `names` with their
/// `distances` [m] (one each; -1: nothing hit).
lcmt_range_finders RangeFinderReadings(const std::string& robot_name,
                                       const std::vector<std::string>& names,
                                       const std::vector<double>& distances, int64_t utime);

/// What a SIM_COMMAND asks of the simulator, checked against the scene by the thread that
/// received it, applied by the loop between two steps (ApplySimRequest).
struct SimRequest {
  enum Kind { kMove, kAttach, kDetach, kPush, kFriction, kSlide } kind = kMove;
  int id = -1;  ///< body (move, push, friction, slide) or weld equality (attach, detach)
  pinocchio::SE3 pose = pinocchio::SE3::Identity();  ///< move, slide: X_WB
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   ///< push: [N], world axes
  double duration_s = 0.0;                           ///< push, slide: [s]
  double friction = 0.0;                             ///< friction: sliding coefficient
  int64_t hash = 0;                                  ///< the message's, for a journal
};

/// Why a SIM_COMMAND is refused: a category to count it under and a detail to log.
struct SimCommandRefusal {
  std::string category, detail;
};

/// The request `msg` makes of `scene`, whose free bodies are `free_objects` (MuJoCo ids
/// `free_object_ids`; a slide moves a mocap body), or why it is refused: an unknown command, weld
/// or object, a non-finite or non-unit pose, a non-finite force or duration. One reading for both
/// simulators (marionette-controller's mujoco backend, marionette-sim).
std::variant<SimRequest, SimCommandRefusal> ReadSimCommand(
    const lcmt_sim_command& msg, const sim::MujocoScene& scene,
    const std::vector<std::string>& free_objects, const std::vector<int>& free_object_ids);

/// Applies a request from ReadSimCommand to the scene it was read for (from the loop, between
/// two steps).
void ApplySimRequest(sim::MujocoScene& scene, const SimRequest& request);

}  // namespace marionette::controller
