#pragma once
/// RobotModel: one Pinocchio kinematics pass per tick, shared by every feature.
/// @entity  inputs: configuration (nq)   outputs: kinematics (Kinematics at that q)

#include <Eigen/Core>
#include <string>

#include "marionette/graph/entity.h"
#include "marionette/sot/kinematics.h"

namespace marionette::sot {

class RobotModel final : public graph::Entity {
 public:
  /// Works for free-flyer, planar and fixed-base robots alike.
  RobotModel(std::string name, ModelPtr model);
  const char* type_name() const override { return "RobotModel"; }

  graph::InputSignal<Eigen::VectorXd>& configuration_input() { return *configuration_; }
  graph::OutputSignal<Kinematics>& kinematics_output() { return *kinematics_; }
  const ModelPtr& model() const { return model_; }

 private:
  void CalcKinematics(const graph::Tick& t, Kinematics* out) const;

  ModelPtr model_;
  graph::InputSignal<Eigen::VectorXd>* configuration_{};
  graph::OutputSignal<Kinematics>* kinematics_{};
};

}  // namespace marionette::sot
