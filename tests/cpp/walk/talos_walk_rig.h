#pragma once
// TALOS walking in MuJoCo with the graph the controller runs (controller.h), built directly:
//   device (MuJoCo) → measured_base → robot → features → tasks → solver → command → device
//   steps (FootstepManager) → pg (PatternGenerator) → CoM task;  steps → feet tasks
// Stack: level 0 joint limits; level 1 left foot 6D, right foot 6D, CoM 3D (references from the
// walk); level 2 posture (the start posture).
#include <mujoco/mujoco.h>

#include <memory>
#include <string>

#include "example_robots.h"
#include "marionette/controller/measured_base.h"
#include "marionette/graph/graph.h"
#include "marionette/sim/mujoco_device.h"
#include "marionette/sot/feature_com.h"
#include "marionette/sot/feature_posture.h"
#include "marionette/sot/feature_se3.h"
#include "marionette/sot/joint_limits.h"
#include "marionette/sot/kinematic_device.h"
#include "marionette/sot/robot_model.h"
#include "marionette/sot/solver.h"
#include "marionette/walk/footstep_manager.h"
#include "marionette/walk/pattern_generator.h"
#include "marionette/walk/support_polygon.h"

namespace marionette::walk::testing {

struct WalkRigOptions {
  std::string scene;  // MJCF with a keyframe (the robot standing)
  // The CoM gain is low on purpose: the CoM feature sees the measured base, so its feedback closes
  // a loop through the compliant servos; at 10/s and above the body's sway is under-damped and
  // the measured ZMP rides the sole edges (at 40/s TALOS falls), at 3-5/s it walks with margin.
  double foot_gain = 20.0, com_gain = 5.0, posture_gain = 2.0;
  // Features at the measured base (the controller's MeasuredBase) or at the integrated command
  // (the Stack of Tasks' device: the free flyer integrated from the solution, open loop; TALOS
  // falls within a few steps that way: the stance leg's compliance is never corrected).
  bool measured_base = true;
  FootstepManagerOptions manager;
};

struct WalkRig {
  sot::ModelPtr model;
  std::unique_ptr<sim::MujocoScene> scene;
  std::unique_ptr<graph::Graph> graph;
  sim::MujocoDevice* device{};
  sot::KinematicDevice* command{};
  sot::RobotModel* robot{};
  FootstepManager* steps{};
  PatternGenerator* pg{};
  sot::Solver* solver{};
  Eigen::VectorXd q0;
  graph::Tick tick;

  void Step() {
    device->Read(tick);
    graph->Evaluate(tick);
    device->Write(tick);
    // The manager's status outputs, for the checks (the stack pulls only the feet).
    steps->phase_output().Eval(tick);
    steps->step_index_output().Eval(tick);
    steps->zmp_reference_output().Eval(tick);
    steps->support_output().Eval(tick);
    ++tick;
  }
  // Sole wrenches with the soles' ground-truth origins (MuJoCo).
  int SoleWrenches(SoleWrench out[2]) const {
    const char* bodies[2] = {"left_sole_link", "right_sole_link"};
    for (int i = 0; i < 2; ++i) {
      const Eigen::VectorXd& w = device->wrench_output(i).value();
      out[i].origin = scene->BodyPose(bodies[i]).translation();
      out[i].force = w.head<3>();
      out[i].torque = w.tail<3>();
    }
    return 2;
  }
  FootPlacement SolePlacement(int side) const {
    return PoseToPlacement(
        scene->BodyPose(side == FootstepManager::kLeft ? "left_sole_link" : "right_sole_link"));
  }
};

inline WalkRig BuildWalkRig(const WalkRigOptions& o) {
  WalkRig r;
  r.model = sot::LoadTalos();
  r.scene = std::make_unique<sim::MujocoScene>(o.scene, *r.model);
  mjData& d = r.scene->mutable_data();
  mj_resetDataKeyframe(&r.scene->model(), &d, 0);
  mj_forward(&r.scene->model(), &d);
  r.q0.resize(r.model->nq);
  Eigen::VectorXd v0(r.model->nv);
  r.scene->ReadRobotState(r.q0, v0);

  sot::Kinematics k0(r.model);
  k0.Compute(r.q0);
  const sot::FrameRef left = sot::MakeFrameRef(*r.model, "left_sole_link", "rig");
  const sot::FrameRef right = sot::MakeFrameRef(*r.model, "right_sole_link", "rig");
  const FootPlacement left0 = PoseToPlacement(k0.placement(left));
  const FootPlacement right0 = PoseToPlacement(k0.placement(right));
  const Eigen::Vector3d com0 = k0.com();

  graph::GraphBuilder b;
  r.device = &b.Add<sim::MujocoDevice>(
      "device", r.scene.get(), std::vector<std::string>{"left_sole_link", "right_sole_link"}, 1e-3);
  r.command = &b.Add<sot::KinematicDevice>("command", r.model, r.q0);
  auto& measured = b.Add<controller::MeasuredBase>("measured_base", r.model->nq, 7);
  b.Connect(r.command->configuration_output(), measured.q_command_input());
  b.Connect(r.device->q_output(), measured.q_measured_input());
  b.Connect(r.command->configuration_output(), r.device->q_command_input());
  r.robot = &b.Add<sot::RobotModel>("robot", r.model);
  b.Connect(o.measured_base ? measured.q_output() : r.command->configuration_output(),
            r.robot->configuration_input());
  auto& kin = r.robot->kinematics_output();

  r.steps = &b.Add<FootstepManager>("steps", left0, right0, com0.head<2>(), o.manager);
  PreviewControlParams params;
  params.dt = o.manager.dt;
  params.preview_time = o.manager.preview_samples * o.manager.dt;
  params.com_height = com0.z() - 0.5 * (left0.z() + right0.z());
  r.pg = &b.Add<PatternGenerator>("pg", params, com0);
  b.Connect(r.steps->zmp_window_output(), r.pg->zmp_window_input());

  auto& lf = b.Add<sot::FeatureSE3>("left_foot_feature", r.model, "left_sole_link");
  auto& rf = b.Add<sot::FeatureSE3>("right_foot_feature", r.model, "right_sole_link");
  auto& com = b.Add<sot::FeatureCom>("com_feature", r.model);
  // The waist stays upright (roll and pitch of base_link at 0; yaw free to turn with the feet):
  // without it the least-norm solution shifts the CoM partly by rolling the whole body.
  auto& waist = b.Add<sot::FeatureSE3>("waist_feature", r.model, "base_link",
                                       sot::Mask{false, false, false, true, true, false});
  auto& posture = b.Add<sot::FeaturePosture>("posture_feature", r.model);
  posture.reference_input().SetValue(r.q0);
  for (sot::Feature* f : std::initializer_list<sot::Feature*>{&lf, &rf, &com, &waist, &posture}) {
    b.Connect(kin, f->kinematics_input());
  }
  b.Connect(r.steps->left_foot_output(), lf.reference_input());
  b.Connect(r.steps->left_foot_velocity_output(), lf.reference_velocity_input());
  b.Connect(r.steps->right_foot_output(), rf.reference_input());
  b.Connect(r.steps->right_foot_velocity_output(), rf.reference_velocity_input());
  b.Connect(r.pg->com_output(), com.reference_input());
  b.Connect(r.pg->com_velocity_output(), com.reference_velocity_input());
  auto& lt = b.Add<sot::Task>("left_foot", lf, sot::Gain::Constant(o.foot_gain));
  auto& rt = b.Add<sot::Task>("right_foot", rf, sot::Gain::Constant(o.foot_gain));
  auto& ct = b.Add<sot::Task>("com", com, sot::Gain::Constant(o.com_gain));
  auto& wt = b.Add<sot::Task>("waist", waist, sot::Gain::Constant(o.foot_gain));
  auto& pt = b.Add<sot::Task>("posture", posture, sot::Gain::Constant(o.posture_gain));
  auto& limits = sot::AddJointLimits(b, "limits", r.model, kin);
  r.solver = &b.Add<sot::Solver>("sot", r.model->nv,
                                 sot::Solver::Levels{{&limits}, {&lt, &rt, &ct, &wt}, {&pt}});
  b.Connect(r.solver->velocity_output(), r.command->command_input());
  b.Connect(r.solver->velocity_output(), r.device->v_command_input());
  r.graph = b.Build();
  return r;
}

}  // namespace marionette::walk::testing
