#pragma once
/// Pose of a frame F against a reference pose D, both in world (Nicolin 2022 eq. 5.1):
///   e     = log6(X_WD^-1 X_WF) = log6(X_DF)                         (6: linear, angular)
///   J     = Jlog6(X_DF) J_F                                          (J_F: frame Jacobian in F)
///   ∂e/∂t = -Jlog6(X_DF) Ad(X_FD) ν_D                                (ν_D: twist of D in D)
/// The mask keeps components of the log (x y z rx ry rz).
/// @entity  inputs: kinematics, reference (SE3 X_WD, default identity),
///          reference_velocity (6: linear velocity of D's origin and angular velocity, world axes;
///          default 0)   outputs: terms, error (k), jacobian (k x nv)

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeatureSE3 final : public Feature {
 public:
  /// Throws SotError on an unknown frame or a bad mask.
  FeatureSE3(std::string name, ModelPtr model, const std::string& frame, const Mask& mask = {});
  const char* type_name() const override { return "FeatureSE3"; }
  graph::InputSignal<pinocchio::SE3>& reference_input() { return *reference_; }
  graph::InputSignal<Eigen::VectorXd>& reference_velocity_input() { return *reference_velocity_; }
  const FrameRef& frame() const { return frame_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  FrameRef frame_;
  graph::InputSignal<pinocchio::SE3>* reference_{};
  graph::InputSignal<Eigen::VectorXd>* reference_velocity_{};
  mutable Matrix6Xd J_F_;  // scratch (6 x nv), zero outside frame_.columns
};

/// ν_D, the body twist of frame D (in D), from its twist in the axes of its parent frame P
/// (linear velocity of D's origin, angular velocity), given R_PD.
Eigen::Matrix<double, 6, 1> BodyTwistFromParentAxes(
    const Eigen::Matrix3d& R_PD, const Eigen::Ref<const Eigen::VectorXd>& twist_P);

}  // namespace marionette::sot
