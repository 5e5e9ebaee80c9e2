#include "marionette/sot/feature_position.h"

namespace marionette::sot {

FeaturePosition::FeaturePosition(std::string name, ModelPtr model, const std::string& frame,
                                 const Mask& mask)
    : Feature(std::move(name), std::move(model), 3, mask) {
  frame_ = MakeFrameRef(*model_, frame, who());
  J_F_ = Matrix6Xd::Zero(6, model_->nv);
  reference_ = &DeclareParameter<Eigen::VectorXd>("reference", Eigen::VectorXd::Zero(3));
  reference_velocity_ =
      &DeclareParameter<Eigen::VectorXd>("reference_velocity", Eigen::VectorXd::Zero(3));
  DeclareTermsOutput({reference_, reference_velocity_});
}

void FeaturePosition::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                                  FeatureTerms* full) const {
  const pinocchio::SE3& X_WF = kinematics.placement(frame_);
  full->error = X_WF.translation() - reference_->Eval(t);
  LocalFrameJacobian(kinematics, frame_, J_F_);
  // ṗ_WF = R_WF v_F (linear part of the body twist).
  for (int c : frame_.columns) {
    full->jacobian.col(c).noalias() = X_WF.rotation() * J_F_.col(c).head<3>();
  }
  full->drift = -reference_velocity_->Eval(t);
}

}  // namespace marionette::sot
