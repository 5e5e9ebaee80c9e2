#include "marionette/sot/kinematic_device.h"

#include <cmath>

#include <pinocchio/algorithm/joint-configuration.hpp>

namespace marionette::sot {

void CheckConfiguration(const pinocchio::Model& model, const Eigen::VectorXd& q,
                        const std::string& who) {
  if (q.size() != model.nq) {
    throw SotError(who + ": configuration of size " + std::to_string(q.size()) + ", model '" +
                   model.name + "' has nq = " + std::to_string(model.nq));
  }
  if (!q.allFinite()) throw SotError(who + ": configuration is not finite");
  if (!pinocchio::isNormalized(model, q, 1e-6)) {
    throw SotError(who +
                   ": configuration has a non-unit quaternion or complex number "
                   "(normalize the base orientation)");
  }
}

KinematicDevice::KinematicDevice(std::string name, ModelPtr model, const Eigen::VectorXd& q0)
    : Entity(std::move(name)), model_(std::move(model)) {
  if (!model_) throw SotError("KinematicDevice '" + this->name() + "': null model");
  CheckConfiguration(*model_, q0, "KinematicDevice '" + this->name() + "'");
  step_ = Eigen::VectorXd::Zero(model_->nv);
  command_ = &DeclareInput<Eigen::VectorXd>("command", Eigen::VectorXd::Zero(model_->nv));
  configuration_ = &DeclareState<Eigen::VectorXd>(
      "configuration", q0, &KinematicDevice::UpdateConfiguration, {command_});
  velocity_ = &DeclareState<Eigen::VectorXd>("velocity", Eigen::VectorXd::Zero(model_->nv),
                                             &KinematicDevice::UpdateVelocity, {command_});
}

void KinematicDevice::UpdateConfiguration(const graph::Tick& t, const Eigen::VectorXd& q,
                                          Eigen::VectorXd* next) const {
  step_ = command_->Eval(t) * t.dt;
  pinocchio::integrate(*model_, q, step_, *next);
}

void KinematicDevice::UpdateVelocity(const graph::Tick& t, const Eigen::VectorXd&,
                                     Eigen::VectorXd* next) const {
  *next = command_->Eval(t);
}

}  // namespace marionette::sot
