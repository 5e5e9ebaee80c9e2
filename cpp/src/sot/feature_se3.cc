#include "marionette/sot/feature_se3.h"

namespace marionette::sot {

Eigen::Matrix<double, 6, 1> BodyTwistFromParentAxes(
    const Eigen::Matrix3d& R_PD, const Eigen::Ref<const Eigen::VectorXd>& twist_P) {
  Eigen::Matrix<double, 6, 1> nu;
  nu.head<3>().noalias() = R_PD.transpose() * twist_P.head<3>();
  nu.tail<3>().noalias() = R_PD.transpose() * twist_P.tail<3>();
  return nu;
}

FeatureSE3::FeatureSE3(std::string name, ModelPtr model, const std::string& frame, const Mask& mask)
    : Feature(std::move(name), std::move(model), 6, mask) {
  frame_ = MakeFrameRef(*model_, frame, who());
  J_F_ = Matrix6Xd::Zero(6, model_->nv);
  reference_ = &DeclareParameter<pinocchio::SE3>("reference", pinocchio::SE3::Identity());
  reference_velocity_ =
      &DeclareParameter<Eigen::VectorXd>("reference_velocity", Eigen::VectorXd::Zero(6));
  DeclareTermsOutput({reference_, reference_velocity_});
}

void FeatureSE3::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                             FeatureTerms* full) const {
  const pinocchio::SE3& X_WD = reference_->Eval(t);
  const pinocchio::SE3 X_DF = X_WD.actInv(kinematics.placement(frame_));
  full->error = pinocchio::log6(X_DF).toVector();
  // Zeroed: GCC cannot see that Jlog6 writes every coefficient (-Wmaybe-uninitialized).
  Eigen::Matrix<double, 6, 6> Jlog = Eigen::Matrix<double, 6, 6>::Zero();
  pinocchio::Jlog6(X_DF, Jlog);
  LocalFrameJacobian(kinematics, frame_, J_F_);
  for (int c : frame_.columns) full->jacobian.col(c).noalias() = Jlog * J_F_.col(c);
  // Moving reference: the twist of X_DF gains -Ad(X_FD) ν_D (see header).
  const auto nu_D = BodyTwistFromParentAxes(X_WD.rotation(), reference_velocity_->Eval(t));
  full->drift.noalias() = -Jlog * X_DF.actInv(pinocchio::Motion(nu_D)).toVector();
}

}  // namespace marionette::sot
