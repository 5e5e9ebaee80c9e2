#pragma once
/// Position-based visual servoing of a gripper G on an object O (Nicolin 2022 §5.2.2,
/// eq. 5.1–5.3). A camera C measures both the gripper (X_CGm) and the object (X_COm); the
/// reference of the proprioceptive gripper is shifted by the measured gripper error (eq. 5.2),
/// so the error only involves measured poses (eq. 5.3) and camera calibration errors cancel:
///   E = (X_COm X_OG*)^-1 X_CGm          (measured gripper in the desired gripper frame G*)
///   e = log6(E),   J = Jlog6(E) J_G,    ∂e/∂t = 0
/// X_OG* (grasp) is the desired gripper pose in the object frame (identity: frames coincide).
/// J assumes the measured gripper moves rigidly with the model gripper (exact when the
/// measurement error is a camera-pose error, first order otherwise).
/// @entity  inputs: kinematics, measured_gripper (SE3 X_CGm), measured_object (SE3 X_COm),
///          grasp (SE3 X_OG*, default identity)   outputs: terms, error, jacobian

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeaturePbvs final : public Feature {
 public:
  FeaturePbvs(std::string name, ModelPtr model, const std::string& gripper_frame,
              const Mask& mask = {});
  const char* type_name() const override { return "FeaturePbvs"; }
  graph::InputSignal<pinocchio::SE3>& measured_gripper_input() { return *measured_gripper_; }
  graph::InputSignal<pinocchio::SE3>& measured_object_input() { return *measured_object_; }
  graph::InputSignal<pinocchio::SE3>& grasp_input() { return *grasp_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  FrameRef gripper_;
  graph::InputSignal<pinocchio::SE3>* measured_gripper_{};
  graph::InputSignal<pinocchio::SE3>* measured_object_{};
  graph::InputSignal<pinocchio::SE3>* grasp_{};
  mutable Matrix6Xd J_G_;
};

}  // namespace marionette::sot
