#pragma once
// The reference TALOS stack of the sot tests and benchmark:
//   level 0  joint position/velocity limits (inequality)
//   level 1  left foot 6D, right foot 6D, CoM 3D          (held where they are)
//   level 2  right gripper 6D (reach target), left gripper relative to right 6D (held)
//   level 3  posture 32D (half-sitting)
// driven by a KinematicDevice from half-sitting (both gripper joints start on a limit).
#include <memory>
#include <string>

#include <pinocchio/algorithm/joint-configuration.hpp>

#include "example_robots.h"
#include "marionette/graph/graph.h"
#include "marionette/sot/feature_com.h"
#include "marionette/sot/feature_posture.h"
#include "marionette/sot/feature_relative_se3.h"
#include "marionette/sot/feature_se3.h"
#include "marionette/sot/joint_limits.h"
#include "marionette/sot/kinematic_device.h"
#include "marionette/sot/robot_model.h"
#include "marionette/sot/solver.h"

namespace marionette::sot::testing {

struct TalosStackOptions {
  double foot_gain = 10.0, com_gain = 10.0, hand_gain = 1.0, relative_gain = 1.0,
         posture_gain = 1.0;
  Eigen::Vector3d reach{0.10, -0.05, 0.10};  // right gripper target - start, world [m]
  bool joint_limits = true;
  bool relative_hand = true;
  SolverOptions solver;
};

struct TalosStack {
  ModelPtr model;
  Eigen::VectorXd q0;
  std::unique_ptr<graph::Graph> graph;
  KinematicDevice* device{};
  RobotModel* robot{};
  Solver* solver{};
  Task *limits{}, *left_foot{}, *right_foot{}, *com{}, *right_hand{}, *left_hand{}, *posture{};
  FeatureSE3* right_hand_feature{};
};

inline const char* kRightGripper = "gripper_right_base_link";
inline const char* kLeftGripper = "gripper_left_base_link";

inline TalosStack BuildTalosStack(const TalosStackOptions& o = {}, ModelPtr model = nullptr) {
  TalosStack s;
  s.model = model ? model : LoadTalos();
  s.q0 = s.model->referenceConfigurations.at("half_sitting");
  Kinematics k0(s.model);
  k0.Compute(s.q0);
  graph::GraphBuilder b;
  s.device = &b.Add<KinematicDevice>("device", s.model, s.q0);
  s.robot = &b.Add<RobotModel>("robot", s.model);
  b.Connect(s.device->configuration_output(), s.robot->configuration_input());
  auto& kin = s.robot->kinematics_output();
  auto frame_pose = [&](const std::string& frame) {
    return k0.placement(MakeFrameRef(*s.model, frame, "test"));
  };
  auto& lf = b.Add<FeatureSE3>("left_foot_feature", s.model, "left_sole_link");
  lf.reference_input().SetValue(frame_pose("left_sole_link"));
  auto& rf = b.Add<FeatureSE3>("right_foot_feature", s.model, "right_sole_link");
  rf.reference_input().SetValue(frame_pose("right_sole_link"));
  auto& com = b.Add<FeatureCom>("com_feature", s.model);
  com.reference_input().SetValue(k0.com());
  auto& rh = b.Add<FeatureSE3>("right_hand_feature", s.model, kRightGripper);
  pinocchio::SE3 target = frame_pose(kRightGripper);
  target.translation() += o.reach;
  rh.reference_input().SetValue(target);
  auto& lh = b.Add<FeatureRelativeSE3>("left_hand_feature", s.model, kLeftGripper, kRightGripper);
  lh.reference_input().SetValue(frame_pose(kRightGripper).actInv(frame_pose(kLeftGripper)));
  auto& posture = b.Add<FeaturePosture>("posture_feature", s.model);
  posture.reference_input().SetValue(s.q0);
  for (Feature* f : std::initializer_list<Feature*>{&lf, &rf, &com, &rh, &lh, &posture}) {
    b.Connect(kin, f->kinematics_input());
  }
  s.left_foot = &b.Add<Task>("left_foot", lf, Gain::Constant(o.foot_gain));
  s.right_foot = &b.Add<Task>("right_foot", rf, Gain::Constant(o.foot_gain));
  s.com = &b.Add<Task>("com", com, Gain::Constant(o.com_gain));
  s.right_hand = &b.Add<Task>("right_hand", rh, Gain::Constant(o.hand_gain));
  s.left_hand = &b.Add<Task>("left_hand", lh, Gain::Constant(o.relative_gain));
  s.posture = &b.Add<Task>("posture", posture, Gain::Constant(o.posture_gain));
  s.right_hand_feature = &rh;
  Solver::Levels levels;
  if (o.joint_limits) {
    s.limits = &AddJointLimits(b, "limits", s.model, kin);
    levels.push_back({s.limits});
  }
  levels.push_back({s.left_foot, s.right_foot, s.com});
  if (o.relative_hand) {
    levels.push_back({s.right_hand, s.left_hand});
  } else {
    levels.push_back({s.right_hand});
  }
  levels.push_back({s.posture});
  s.solver = &b.Add<Solver>("sot", s.model->nv, levels, o.solver);
  b.Connect(s.solver->velocity_output(), s.device->command_input());
  s.graph = b.Build();
  return s;
}

}  // namespace marionette::sot::testing
