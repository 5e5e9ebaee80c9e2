#include "marionette/sot/feature_com.h"

namespace marionette::sot {

FeatureCom::FeatureCom(std::string name, ModelPtr model, const Mask& mask)
    : Feature(std::move(name), std::move(model), 3, mask) {
  reference_ = &DeclareParameter<Eigen::VectorXd>("reference", Eigen::VectorXd::Zero(3));
  reference_velocity_ =
      &DeclareParameter<Eigen::VectorXd>("reference_velocity", Eigen::VectorXd::Zero(3));
  DeclareTermsOutput({reference_, reference_velocity_});
}

void FeatureCom::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                             FeatureTerms* full) const {
  full->error = kinematics.com() - reference_->Eval(t);
  full->jacobian = kinematics.com_jacobian();
  full->drift = -reference_velocity_->Eval(t);
}

}  // namespace marionette::sot
