#pragma once
/// ControllerFactory: turns a controller spec (lcmt_controller_spec, received over LCM) into the
/// entities of one controller — for each task a feature and a Task (plus a ReferenceStream when
/// the task's reference is streamed), the joint-limit task at level 0, and a Solver — packed in
/// a GraphEdit that also removes the previous controller and plugs the new solver in front of
/// the safety filter. Everything here runs off the loop thread; the loop only applies the edit.
///
/// Task kinds (lcmt_task_spec.kind) and their references (fixed `reference`, or streamed on
/// TASK_REFERENCE with the task's name):
///   se3, pbvs     frame pose X_WD            7 values (x y z qw qx qy qz), derivative 6
///                 ("pbvs": the reference is the visual one streamed by perception, eq. 5.2)
///   relative_se3  pose of frame relative to frame_b, X_BD   7 values, derivative 6
///   position      frame origin p_W          3 values, derivative 3
///   com           centre of mass c_W         3 values, derivative 3
///   posture       configuration q            nq values, derivative nv (joints: joint_name)
///   gaze          world point kept at the image centre   3 values, derivative 3
///   gripper_admittance  a gripper joint's position then force (gripper_admittance_spec.h)
///                 position target [rad]   1 value, fixed only
/// Walking (Dang 2012 §2.6.2–2.6.3): a task whose reference_channel is "walk:left_foot" or
/// "walk:right_foot" (kind se3, its frame a sole), "walk:com" (kind com) or "walk:waist" (kind
/// se3: turning with the feet's mean yaw, as it stood at the swap) takes its reference and
/// feed-forward from a FootstepManager + PatternGenerator pair added to the controller; the two
/// feet tasks are then required (their frames are the soles the manager starts from). At the swap
/// both start standing where the robot is; footstep plans (FOOTSTEP_PLAN) are posted to the active
/// controller's manager (BuiltController::walk_steps). An unset fixed reference means "hold where
/// it is now": the reference (and a stream's initial value) is the feature's value at the tick the
/// controller is swapped in (BuiltController::HoldCurrent, run by the loop: no allocation), so a
/// hold never pulls towards a stale pose.

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "marionette/controller/reference_stream.h"
#include "marionette/graph/graph.h"
#include "marionette/lcmt_controller_spec.hpp"
#include "marionette/sot/kinematics.h"
#include "marionette/sot/robot_model.h"
#include "marionette/walk/footstep_manager.h"
#include "marionette/walk/pattern_generator.h"

namespace marionette::controller {

/// One controller ready to be swapped in.
struct BuiltController {
  int64_t id = 0;
  std::string name;
  double max_switch_velocity_jump = 0.0;  ///< [rad/s] refuse the swap above this ‖Δv‖∞
  double reference_timeout = 0.0;         ///< [s] watchdog on the streamed references
  std::unique_ptr<graph::GraphEdit> edit;
  graph::OutputSignal<Eigen::VectorXd>* velocity = nullptr;  ///< the solver's command
  graph::OutputSignal<Eigen::VectorXd>* unblended_velocity =
      nullptr;  ///< its solution without the switch blend
  std::vector<std::string> task_names;
  std::vector<graph::OutputSignal<double>*> task_errors;  ///< ‖e‖ per task, same order
  std::map<std::string, ReferenceStream*> streams;        ///< by task name
  std::vector<std::string> entity_names;                  ///< removed by the next controller's edit
  /// Walking entities, when a task takes a "walk:" reference (nullptr otherwise).
  walk::FootstepManager* walk_steps = nullptr;
  walk::PatternGenerator* walk_pattern = nullptr;
  /// The balance tasks of the spec: its first level's se3, position and com tasks that are not
  /// streamed (walk references, fixed or held ones: feet, CoM, waist) — what a hold controller
  /// keeps of a walking controller to finish the step in progress (hold_controller.h).
  std::vector<lcmt_task_spec> balance_tasks;

  /// Sets every "hold where it is" reference to the current value of its feature (loop thread,
  /// at the swap: no allocation).
  void HoldCurrent(const sot::Kinematics& now) const {
    for (const auto& hold : holds) hold(now);
  }
  std::vector<std::function<void(const sot::Kinematics&)>> holds;
};

/// The persistent entities a controller plugs into.
struct ControllerSockets {
  graph::OutputSignal<sot::Kinematics>* kinematics = nullptr;        ///< RobotModel.kinematics
  graph::InputSignal<Eigen::VectorXd>* command = nullptr;            ///< SafetyFilter.velocity
  graph::OutputSignal<Eigen::VectorXd>* applied_velocity = nullptr;  ///< last applied command
  /// Measured actuator efforts (nv) and configuration (nq) for gripper_admittance tasks
  /// (MujocoDevice.effort / .q); nullptr without a simulated or real device (kinematic backend:
  /// the effort stays 0, the gripper closes in position control).
  graph::OutputSignal<Eigen::VectorXd>* effort = nullptr;
  graph::OutputSignal<Eigen::VectorXd>* q_measured = nullptr;
};

class ControllerFactory {
 public:
  /// `held_velocities`: velocity components no device executes (sot::FeatureHeldVelocities):
  /// every controller holds them at zero at level 0, beside the joint limits.
  ControllerFactory(sot::ModelPtr model, ControllerSockets sockets, double default_gain = 2.0,
                    std::vector<int> held_velocities = {});

  /// Builds the controller of `spec` against `graph`, replacing the controller whose entities are
  /// `previous_entities`; `q` (nq) is a recent configuration (to check the spec against). Throws
  /// std::invalid_argument naming the task and the problem (unknown kind, frame or joint, bad
  /// mask, gain or reference, duplicate names...). The returned edit is prepared.
  /// With `continue_walk` (a running walking controller whose walk entities are not among
  /// `previous_entities`), the spec's "walk:" tasks take their references from its footstep
  /// manager and pattern generator, which the new controller adopts as they are (the walk goes
  /// on), instead of new ones starting standing.
  std::unique_ptr<BuiltController> Build(const lcmt_controller_spec& spec,
                                         const graph::Graph& graph,
                                         const std::vector<std::string>& previous_entities,
                                         const Eigen::VectorXd& q,
                                         const BuiltController* continue_walk = nullptr) const;

  /// The value size and derivative size of a task kind's reference (throws on an unknown kind).
  std::pair<int, int> ReferenceSizes(const std::string& kind) const;

 private:
  sot::ModelPtr model_;
  ControllerSockets sockets_;
  double default_gain_;
  std::vector<int> held_velocities_;
};

}  // namespace marionette::controller
