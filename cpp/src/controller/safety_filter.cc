#include "marionette/controller/safety_filter.h"

#include <algorithm>
#include <cmath>

namespace marionette::controller {

SafetyFilter::SafetyFilter(std::string name, const pinocchio::Model& model, double dt,
                           double velocity_scale)
    : Entity(std::move(name)), dt_(dt) {
  if (!(dt_ > 0.0) || !(velocity_scale > 0.0 && velocity_scale <= 1.0)) {
    throw graph::GraphError("safety filter '" + this->name() +
                            "': needs dt > 0 and 0 < velocity_scale <= 1");
  }
  for (pinocchio::JointIndex j = 1; j < model.joints.size(); ++j) {
    const auto& joint = model.joints[j];
    if (joint.nq() != 1 || joint.nv() != 1) continue;  // the base is not commanded
    const int iq = joint.idx_q(), iv = joint.idx_v();
    limits_.push_back(Limit{iq, iv, model.lowerPositionLimit[iq], model.upperPositionLimit[iq],
                            velocity_scale * model.upperVelocityLimit[iv]});
  }
  velocity_in_ = &DeclareInput<Eigen::VectorXd>("velocity", Eigen::VectorXd::Zero(model.nv));
  q_ = &DeclareInput<Eigen::VectorXd>("q", Eigen::VectorXd::Zero(model.nq));
  mode_ = &DeclareParameter<int>("mode", static_cast<int>(ControlMode::kHold), /*settable=*/false);
  velocity_out_ =
      &DeclareOutput<Eigen::VectorXd>("command", Eigen::VectorXd::Zero(model.nv),
                                      &SafetyFilter::CalcVelocity, {velocity_in_, q_, mode_});
  num_clamped_ = &DeclareOutput<int>("num_clamped", 0, &SafetyFilter::CalcNumClamped,
                                     {velocity_in_, velocity_out_, mode_});
  non_finite_ = &DeclareOutput<bool>("non_finite", false, &SafetyFilter::CalcNonFinite,
                                     {velocity_in_, mode_});
}

void SafetyFilter::CalcVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
  if (mode_->Eval(t) != static_cast<int>(ControlMode::kRun)) {
    out->setZero();
    return;
  }
  const Eigen::VectorXd& v = velocity_in_->Eval(t);
  if (!v.allFinite()) {
    out->setZero();
    return;
  }
  const Eigen::VectorXd& q = q_->Eval(t);
  *out = v;
  for (const Limit& l : limits_) {
    // Stay inside [lower, upper] after one step; a joint already outside may only come back.
    const double lo = std::max(-l.max_velocity, std::min(0.0, (l.lower - q[l.idx_q]) / dt_));
    const double hi = std::min(l.max_velocity, std::max(0.0, (l.upper - q[l.idx_q]) / dt_));
    (*out)[l.idx_v] = std::clamp(v[l.idx_v], lo, hi);
  }
}

void SafetyFilter::CalcNumClamped(const graph::Tick& t, int* out) const {
  const Eigen::VectorXd& in = velocity_in_->Eval(t);
  const Eigen::VectorXd& filtered = velocity_out_->Eval(t);
  int n = 0;
  if (mode_->Eval(t) == static_cast<int>(ControlMode::kRun) && in.allFinite()) {
    for (const Limit& l : limits_) n += filtered[l.idx_v] != in[l.idx_v] ? 1 : 0;
  }
  *out = n;
}

void SafetyFilter::CalcNonFinite(const graph::Tick& t, bool* out) const {
  *out =
      mode_->Eval(t) == static_cast<int>(ControlMode::kRun) && !velocity_in_->Eval(t).allFinite();
}

}  // namespace marionette::controller
