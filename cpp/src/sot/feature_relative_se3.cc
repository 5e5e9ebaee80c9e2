#include "marionette/sot/feature_relative_se3.h"

#include <algorithm>

#include "marionette/sot/feature_se3.h"

namespace marionette::sot {

FeatureRelativeSE3::FeatureRelativeSE3(std::string name, ModelPtr model, const std::string& frame_a,
                                       const std::string& frame_b, const Mask& mask)
    : Feature(std::move(name), std::move(model), 6, mask) {
  frame_a_ = MakeFrameRef(*model_, frame_a, who());
  frame_b_ = MakeFrameRef(*model_, frame_b, who());
  if (frame_a_.frame == frame_b_.frame) {
    throw SotError(who() + ": frame_a and frame_b are the same frame '" + frame_a + "'");
  }
  std::set_union(frame_a_.columns.begin(), frame_a_.columns.end(), frame_b_.columns.begin(),
                 frame_b_.columns.end(), std::back_inserter(columns_));
  J_A_ = Matrix6Xd::Zero(6, model_->nv);
  J_B_ = Matrix6Xd::Zero(6, model_->nv);
  reference_ = &DeclareParameter<pinocchio::SE3>("reference", pinocchio::SE3::Identity());
  reference_velocity_ =
      &DeclareParameter<Eigen::VectorXd>("reference_velocity", Eigen::VectorXd::Zero(6));
  DeclareTermsOutput({reference_, reference_velocity_});
}

void FeatureRelativeSE3::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                                     FeatureTerms* full) const {
  const pinocchio::SE3& X_WA = kinematics.placement(frame_a_);
  const pinocchio::SE3& X_WB = kinematics.placement(frame_b_);
  const pinocchio::SE3 X_BA = X_WB.actInv(X_WA);
  const pinocchio::SE3& X_BD = reference_->Eval(t);
  const pinocchio::SE3 E = X_BD.actInv(X_BA);
  full->error = pinocchio::log6(E).toVector();
  // Zeroed: GCC cannot see that Jlog6 writes every coefficient (-Wmaybe-uninitialized).
  Eigen::Matrix<double, 6, 6> Jlog = Eigen::Matrix<double, 6, 6>::Zero();
  pinocchio::Jlog6(E, Jlog);
  LocalFrameJacobian(kinematics, frame_a_, J_A_);
  LocalFrameJacobian(kinematics, frame_b_, J_B_);
  // Twist of A relative to B, in A: ν_A - Ad(X_AB) ν_B.
  const Eigen::Matrix<double, 6, 6> Ad_AB = X_BA.inverse().toActionMatrix();
  const Eigen::Matrix<double, 6, 6> Jlog_Ad = Jlog * Ad_AB;
  for (int c : columns_) {
    full->jacobian.col(c).noalias() = Jlog * J_A_.col(c);
    full->jacobian.col(c).noalias() -= Jlog_Ad * J_B_.col(c);
  }
  const auto nu_D = BodyTwistFromParentAxes(X_BD.rotation(), reference_velocity_->Eval(t));
  full->drift.noalias() = -Jlog * E.actInv(pinocchio::Motion(nu_D)).toVector();
}

}  // namespace marionette::sot
