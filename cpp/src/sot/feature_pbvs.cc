#include "marionette/sot/feature_pbvs.h"

namespace marionette::sot {

FeaturePbvs::FeaturePbvs(std::string name, ModelPtr model, const std::string& gripper_frame,
                         const Mask& mask)
    : Feature(std::move(name), std::move(model), 6, mask) {
  gripper_ = MakeFrameRef(*model_, gripper_frame, who());
  J_G_ = Matrix6Xd::Zero(6, model_->nv);
  measured_gripper_ = &DeclareInput<pinocchio::SE3>("measured_gripper", pinocchio::SE3::Identity(),
                                                    /*settable=*/true);
  measured_object_ = &DeclareInput<pinocchio::SE3>("measured_object", pinocchio::SE3::Identity(),
                                                   /*settable=*/true);
  grasp_ = &DeclareParameter<pinocchio::SE3>("grasp", pinocchio::SE3::Identity());
  DeclareTermsOutput({measured_gripper_, measured_object_, grasp_});
}

void FeaturePbvs::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                              FeatureTerms* full) const {
  // Eq. 5.2–5.3: only the measured relative pose matters, E = X_G*Gm.
  const pinocchio::SE3 X_CGdes = measured_object_->Eval(t) * grasp_->Eval(t);
  const pinocchio::SE3 E = X_CGdes.actInv(measured_gripper_->Eval(t));
  full->error = pinocchio::log6(E).toVector();
  // Zeroed: GCC cannot see that Jlog6 writes every coefficient (-Wmaybe-uninitialized).
  Eigen::Matrix<double, 6, 6> Jlog = Eigen::Matrix<double, 6, 6>::Zero();
  pinocchio::Jlog6(E, Jlog);
  LocalFrameJacobian(kinematics, gripper_, J_G_);
  for (int c : gripper_.columns) full->jacobian.col(c).noalias() = Jlog * J_G_.col(c);
  full->drift.setZero();
}

}  // namespace marionette::sot
