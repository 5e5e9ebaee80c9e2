#pragma once
/// Pose of frame A relative to frame B against a reference X_BD (grasp, handover, tool in hole):
///   X_BA  = X_WB^-1 X_WA,   E = X_BD^-1 X_BA
///   e     = log6(E)
///   J     = Jlog6(E) (J_A - Ad(X_AB) J_B)                 (J_A, J_B: frame Jacobians in A, B)
///   ∂e/∂t = -Jlog6(E) Ad(E^-1) ν_D                        (ν_D: twist of D relative to B, in D)
/// @entity  inputs: kinematics, reference (SE3 X_BD, default identity), reference_velocity (6,
///          twist of D relative to B in B axes, default 0)   outputs: terms, error, jacobian

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeatureRelativeSE3 final : public Feature {
 public:
  /// Throws SotError on unknown frames, frame_a == frame_b, or a bad mask.
  FeatureRelativeSE3(std::string name, ModelPtr model, const std::string& frame_a,
                     const std::string& frame_b, const Mask& mask = {});
  const char* type_name() const override { return "FeatureRelativeSE3"; }
  graph::InputSignal<pinocchio::SE3>& reference_input() { return *reference_; }
  graph::InputSignal<Eigen::VectorXd>& reference_velocity_input() { return *reference_velocity_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  FrameRef frame_a_, frame_b_;
  std::vector<int> columns_;  // union of the columns moving A or B
  graph::InputSignal<pinocchio::SE3>* reference_{};
  graph::InputSignal<Eigen::VectorXd>* reference_velocity_{};
  mutable Matrix6Xd J_A_, J_B_;  // scratch (6 x nv)
};

}  // namespace marionette::sot
