#pragma once
/// Position of a frame's origin in world (3D point task):
///   e = p_WF - p*,   J = R_WF J_F[linear rows],   ∂e/∂t = -ṗ*
/// @entity  inputs: kinematics, reference (3, p* in world, default 0), reference_velocity (3,
///          default 0)   outputs: terms, error, jacobian

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeaturePosition final : public Feature {
 public:
  FeaturePosition(std::string name, ModelPtr model, const std::string& frame,
                  const Mask& mask = {});
  const char* type_name() const override { return "FeaturePosition"; }
  graph::InputSignal<Eigen::VectorXd>& reference_input() { return *reference_; }
  graph::InputSignal<Eigen::VectorXd>& reference_velocity_input() { return *reference_velocity_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  FrameRef frame_;
  graph::InputSignal<Eigen::VectorXd>* reference_{};
  graph::InputSignal<Eigen::VectorXd>* reference_velocity_{};
  mutable Matrix6Xd J_F_;
};

}  // namespace marionette::sot
