#include "marionette/sot/task.h"

#include <algorithm>
#include <cmath>

namespace marionette::sot {

namespace {
constexpr double kInf = std::numeric_limits<double>::infinity();
}

double Gain::operator()(double error_norm) const {
  const double a = at_zero - at_infinity;
  if (slope <= 0.0 || a == 0.0) return at_zero;
  return a * std::exp(-slope / a * error_norm) + at_infinity;
}

void Gain::Check(const std::string& who) const {
  for (double g : {at_zero, at_infinity, slope}) {
    if (!std::isfinite(g) || g < 0.0) {
      throw SotError(who + ": gains must be finite and >= 0 (gain " + std::to_string(at_zero) +
                     ", at infinity " + std::to_string(at_infinity) + ", slope " +
                     std::to_string(slope) + ")");
    }
  }
}

Task::Task(std::string name, Feature& feature, Gain gain) : Entity(std::move(name)) {
  Declare(feature, gain);
}

Task::Task(std::string name, Feature& feature, Gain gain, TaskBounds bounds)
    : Entity(std::move(name)) {
  inequality_ = true;
  const int k = feature.dimension();
  const std::string who = "Task '" + this->name() + "'";
  auto fill = [&](Eigen::VectorXd& v, double value, const char* what) {
    if (v.size() == 0) v = Eigen::VectorXd::Constant(k, value);
    CheckSize(v, k, who, what);
    if (v.hasNaN()) throw SotError(who + ": " + what + " has NaN");
  };
  fill(bounds.error_lower, -kInf, "error_lower");
  fill(bounds.error_upper, kInf, "error_upper");
  fill(bounds.rate_lower, -kInf, "rate_lower");
  fill(bounds.rate_upper, kInf, "rate_upper");
  if ((bounds.error_lower.array() > bounds.error_upper.array()).any() ||
      (bounds.rate_lower.array() > bounds.rate_upper.array()).any()) {
    throw SotError(who + ": a lower bound exceeds its upper bound");
  }
  error_lower_ = &DeclareParameter<Eigen::VectorXd>("error_lower", bounds.error_lower);
  error_upper_ = &DeclareParameter<Eigen::VectorXd>("error_upper", bounds.error_upper);
  rate_lower_ = &DeclareParameter<Eigen::VectorXd>("rate_lower", bounds.rate_lower);
  rate_upper_ = &DeclareParameter<Eigen::VectorXd>("rate_upper", bounds.rate_upper);
  Declare(feature, gain);
}

void Task::Declare(Feature& feature, Gain gain) {
  gain.Check("Task '" + name() + "'");
  feature_ = &feature;
  dimension_ = feature.dimension();
  nv_ = feature.nv();
  feature_terms_ = &DeclareInput<FeatureTerms>("feature", FeatureTerms(dimension_, nv_));
  feature_terms_->Plug(feature.terms_output());
  gain_ = &DeclareParameter<double>("gain", gain.at_zero);
  gain_at_infinity_ = &DeclareParameter<double>("gain_at_infinity", gain.at_infinity);
  gain_slope_ = &DeclareParameter<double>("gain_slope", gain.slope);
  active_ = &DeclareParameter<bool>("active", true);
  std::vector<const graph::SignalBase*> prerequisites{feature_terms_, gain_, gain_at_infinity_,
                                                      gain_slope_, active_};
  if (inequality_) {
    prerequisites.insert(prerequisites.end(),
                         {error_lower_, error_upper_, rate_lower_, rate_upper_});
  }
  gain_value_ = &DeclareOutput<double>("gain_value", gain.at_zero, &Task::CalcGainValue,
                                       {feature_terms_, gain_, gain_at_infinity_, gain_slope_});
  prerequisites.push_back(gain_value_);
  TaskTerms model(dimension_, nv_);
  model.inequality = inequality_;
  model.unit_columns = feature.unit_columns();
  // A constant (unit-row) Jacobian is written once here, not copied every tick.
  for (size_t i = 0; i < model.unit_columns.size(); ++i)
    model.jacobian(i, model.unit_columns[i]) = 1.0;
  terms_ = &DeclareOutput<TaskTerms>("terms", model, &Task::CalcTerms, prerequisites);
  std::vector<const graph::SignalBase*> norm_prerequisites{feature_terms_};
  if (inequality_)
    norm_prerequisites.insert(norm_prerequisites.end(), {error_lower_, error_upper_});
  error_norm_ = &DeclareOutput<double>("error_norm", 0.0, &Task::CalcErrorNorm, norm_prerequisites);
}

void Task::CalcGainValue(const graph::Tick& t, double* out) const {
  const Gain gain{gain_->Eval(t), gain_at_infinity_->Eval(t), gain_slope_->Eval(t)};
  *out = gain(feature_terms_->Eval(t).error.norm());
}

void Task::CalcTerms(const graph::Tick& t, TaskTerms* out) const {
  const FeatureTerms& f = feature_terms_->Eval(t);
  out->active = active_->Eval(t);
  if (out->unit_columns.empty()) out->jacobian = f.jacobian;
  const double lambda = gain_value_->Eval(t);
  if (!inequality_) {
    out->lower.noalias() = -lambda * f.error - f.drift;
    out->upper = out->lower;
    return;
  }
  const Eigen::VectorXd& e_lo = error_lower_->Eval(t);
  const Eigen::VectorXd& e_hi = error_upper_->Eval(t);
  const Eigen::VectorXd& r_lo = rate_lower_->Eval(t);
  const Eigen::VectorXd& r_hi = rate_upper_->Eval(t);
  for (int i = 0; i < dimension_; ++i) {
    // ė = J v + ∂e/∂t must lie in [λ(e_lo - e), λ(e_hi - e)] ∩ [ė_lo, ė_hi].
    const double pl = std::isinf(e_lo[i]) ? -kInf : lambda * (e_lo[i] - f.error[i]);
    const double pu = std::isinf(e_hi[i]) ? kInf : lambda * (e_hi[i] - f.error[i]);
    double lo = std::max(pl, r_lo[i]), hi = std::min(pu, r_hi[i]);
    // Beyond a bound with too slow a rate limit: come back at the fastest allowed rate.
    if (lo > hi) lo = hi = (pl > r_hi[i]) ? r_hi[i] : r_lo[i];
    out->lower[i] = lo - f.drift[i];
    out->upper[i] = hi - f.drift[i];
  }
}

void Task::CalcErrorNorm(const graph::Tick& t, double* out) const {
  const Eigen::VectorXd& e = feature_terms_->Eval(t).error;
  if (!inequality_) {
    *out = e.norm();
    return;
  }
  *out = ViolationNorm(t, e);
}

double Task::ViolationNorm(const graph::Tick& t, const Eigen::VectorXd& e) const {
  const Eigen::VectorXd& e_lo = error_lower_->Eval(t);
  const Eigen::VectorXd& e_hi = error_upper_->Eval(t);
  double sum = 0.0;
  for (int i = 0; i < dimension_; ++i) {
    const double d = std::max({e_lo[i] - e[i], e[i] - e_hi[i], 0.0});
    sum += d * d;
  }
  return std::sqrt(sum);
}

}  // namespace marionette::sot
