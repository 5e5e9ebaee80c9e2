#include "marionette/sot/feature_gaze.h"

#include <algorithm>

namespace marionette::sot {

namespace {
constexpr double kMinDepth = 0.01;  // [m]
}

FeatureGaze::FeatureGaze(std::string name, ModelPtr model, const std::string& camera_frame,
                         const Mask& mask)
    : Feature(std::move(name), std::move(model), 2, mask) {
  camera_ = MakeFrameRef(*model_, camera_frame, who());
  J_C_ = Matrix6Xd::Zero(6, model_->nv);
  target_ = &DeclareInput<Eigen::VectorXd>("target", Eigen::VectorXd::Zero(3), /*settable=*/true);
  desired_ = &DeclareParameter<Eigen::VectorXd>("desired", Eigen::VectorXd::Zero(2));
  target_velocity_ =
      &DeclareParameter<Eigen::VectorXd>("target_velocity", Eigen::VectorXd::Zero(3));
  DeclareTermsOutput({target_, desired_, target_velocity_});
}

void FeatureGaze::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                              FeatureTerms* full) const {
  const pinocchio::SE3& X_WC = kinematics.placement(camera_);
  const Eigen::Vector3d p_C = X_WC.actInv(Eigen::Vector3d(target_->Eval(t)));
  const double Z = std::max(p_C.z(), kMinDepth);
  const double x = p_C.x() / Z, y = p_C.y() / Z;
  full->error = Eigen::Vector2d(x, y) - desired_->Eval(t);
  Eigen::Matrix<double, 2, 3> L_p;
  L_p << 1.0 / Z, 0.0, -x / Z, 0.0, 1.0 / Z, -y / Z;
  // ṗ_C = -v_C + p_C x w_C for a still point, so ∂p_C/∂ν_C = [-I, [p_C]x].
  Eigen::Matrix<double, 2, 6> L;
  L.leftCols<3>() = -L_p;
  L.rightCols<3>().noalias() = L_p * pinocchio::skew(p_C);
  LocalFrameJacobian(kinematics, camera_, J_C_);
  for (int c : camera_.columns) full->jacobian.col(c).noalias() = L * J_C_.col(c);
  full->drift.noalias() = L_p * (X_WC.rotation().transpose() * target_velocity_->Eval(t));
}

}  // namespace marionette::sot
