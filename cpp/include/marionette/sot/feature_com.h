#pragma once
/// Centre of mass in world:  e = c_W - c*,   J = ∂c_W/∂q (Pinocchio's Jcom),   ∂e/∂t = -ċ*
/// @entity  inputs: kinematics, reference (3, default 0), reference_velocity (3, default 0)
///          outputs: terms, error, jacobian

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeatureCom final : public Feature {
 public:
  FeatureCom(std::string name, ModelPtr model, const Mask& mask = {});
  const char* type_name() const override { return "FeatureCom"; }
  graph::InputSignal<Eigen::VectorXd>& reference_input() { return *reference_; }
  graph::InputSignal<Eigen::VectorXd>& reference_velocity_input() { return *reference_velocity_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  graph::InputSignal<Eigen::VectorXd>* reference_{};
  graph::InputSignal<Eigen::VectorXd>* reference_velocity_{};
};

}  // namespace marionette::sot
