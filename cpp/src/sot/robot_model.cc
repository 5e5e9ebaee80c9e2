#include "marionette/sot/robot_model.h"

#include <pinocchio/algorithm/joint-configuration.hpp>

namespace marionette::sot {

RobotModel::RobotModel(std::string name, ModelPtr model)
    : Entity(std::move(name)), model_(std::move(model)) {
  if (!model_) throw SotError("RobotModel '" + this->name() + "': null model");
  configuration_ = &DeclareInput<Eigen::VectorXd>("configuration", pinocchio::neutral(*model_));
  kinematics_ = &DeclareOutput<Kinematics>("kinematics", Kinematics(model_),
                                           &RobotModel::CalcKinematics, {configuration_});
}

void RobotModel::CalcKinematics(const graph::Tick& t, Kinematics* out) const {
  out->Compute(configuration_->Eval(t));
}

}  // namespace marionette::sot
