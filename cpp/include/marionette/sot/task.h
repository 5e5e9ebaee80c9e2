#pragma once
/// Task: a feature plus its desired error dynamics (Nicolin 2022 eq. 3.1–3.4, Dang 2012 eq. 2.20):
///   equality task     ė* = -λ(‖e‖) e        →   J v = -λ e - ∂e/∂t            (k rows)
///   inequality task   e_lo <= e <= e_hi     →   λ (e_lo - e) - ∂e/∂t  <=  J v  <=  λ (e_hi - e) -
///   ∂e/∂t,
///                     optionally also  ė_lo <= J v + ∂e/∂t <= ė_hi  (velocity bounds)
/// The -∂e/∂t term is the feed-forward of a moving reference. λ is constant or adaptive
/// (sot-core GainAdaptive). A task is active or not (`active` parameter): the Solver skips
/// inactive tasks and blends its command when the set of active tasks changes (smooth insertion
/// and removal, Dang 2012 eq. 2.26–2.34).
/// @entity  inputs: feature (plugged to the feature's terms at construction), gain (λ at zero
///          error), gain_at_infinity, gain_slope, active (bool); inequality tasks also
///          error_lower, error_upper, rate_lower, rate_upper (k each)
///          outputs: terms (TaskTerms: J and the bounds of J v), error_norm (‖e‖, or for an
///          inequality task the norm of the bound violation), gain_value (λ used this tick)

#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"
#include "marionette/sot/feature.h"

namespace marionette::sot {

/// What the solver reads from a task each tick: lower <= J v <= upper (lower == upper for an
/// equality task).
struct TaskTerms {
  TaskTerms() = default;
  TaskTerms(int k, int nv)
      : jacobian(Eigen::MatrixXd::Zero(k, nv)),
        lower(Eigen::VectorXd::Zero(k)),
        upper(Eigen::VectorXd::Zero(k)) {}
  Eigen::MatrixXd jacobian;  ///< J (k x nv)
  Eigen::VectorXd lower;     ///< (k)
  Eigen::VectorXd upper;     ///< (k)
  bool inequality = false;
  bool active = true;
  /// Non-empty when row i of J is the constant unit row e_{unit_columns[i]}^T.
  std::vector<int> unit_columns;
};

/// λ(‖e‖) = (λ0 - λ∞) exp(-s ‖e‖ / (λ0 - λ∞)) + λ∞   (sot-core GainAdaptive: λ0 at zero error,
/// λ∞ at large error, slope -s at zero). Constant (λ0) when s == 0 or λ0 == λ∞.
/// From lcmt_task_spec: gain -> at_zero, gain_max -> at_infinity, gain_slope -> slope.
struct Gain {
  double at_zero = 1.0;      ///< λ0 [1/s]
  double at_infinity = 0.0;  ///< λ∞ [1/s] (unused when constant)
  double slope = 0.0;        ///< s [1/(s·unit of e)]; 0 = constant gain
  static Gain Constant(double lambda) { return {lambda, lambda, 0.0}; }
  static Gain Adaptive(double at_zero, double at_infinity, double slope) {
    return {at_zero, at_infinity, slope};
  }
  double operator()(double error_norm) const;
  /// Throws SotError (naming `who`) when a gain is negative or not finite.
  void Check(const std::string& who) const;
};

/// Bounds of an inequality task (k each; ±infinity where unbounded).
struct TaskBounds {
  Eigen::VectorXd error_lower, error_upper;  ///< e_lo, e_hi
  Eigen::VectorXd rate_lower, rate_upper;    ///< ė_lo, ė_hi (empty = unbounded)
};

class Task final : public graph::Entity {
 public:
  /// Equality task on `feature` (plugged here; the feature must be added to the same graph).
  Task(std::string name, Feature& feature, Gain gain);
  /// Inequality task; throws SotError on sizes different from the feature's dimension or on
  /// lower > upper.
  Task(std::string name, Feature& feature, Gain gain, TaskBounds bounds);
  const char* type_name() const override { return "Task"; }

  graph::OutputSignal<TaskTerms>& terms_output() { return *terms_; }
  graph::OutputSignal<double>& error_norm_output() { return *error_norm_; }
  graph::OutputSignal<double>& gain_value_output() { return *gain_value_; }
  graph::InputSignal<bool>& active_input() { return *active_; }
  graph::InputSignal<double>& gain_input() { return *gain_; }
  int dimension() const { return dimension_; }
  int nv() const { return nv_; }
  bool inequality() const { return inequality_; }
  Feature& feature() const { return *feature_; }

 private:
  void Declare(Feature& feature, Gain gain);
  void CalcTerms(const graph::Tick& t, TaskTerms* out) const;
  void CalcErrorNorm(const graph::Tick& t, double* out) const;
  void CalcGainValue(const graph::Tick& t, double* out) const;
  double ViolationNorm(const graph::Tick& t, const Eigen::VectorXd& e) const;

  Feature* feature_;
  int dimension_, nv_;
  bool inequality_ = false;
  graph::InputSignal<FeatureTerms>* feature_terms_{};
  graph::InputSignal<double>* gain_{};
  graph::InputSignal<double>* gain_at_infinity_{};
  graph::InputSignal<double>* gain_slope_{};
  graph::InputSignal<bool>* active_{};
  graph::InputSignal<Eigen::VectorXd>* error_lower_{};
  graph::InputSignal<Eigen::VectorXd>* error_upper_{};
  graph::InputSignal<Eigen::VectorXd>* rate_lower_{};
  graph::InputSignal<Eigen::VectorXd>* rate_upper_{};
  graph::OutputSignal<TaskTerms>* terms_{};
  graph::OutputSignal<double>* error_norm_{};
  graph::OutputSignal<double>* gain_value_{};
};

}  // namespace marionette::sot

namespace marionette::graph {

/// TaskTerms flatten to a k x (nv + 2) matrix [J | lower | upper].
template <>
struct ValueTraits<sot::TaskTerms> {
  static constexpr const char* kName = "task_terms";
  static Shape ShapeOf(const sot::TaskTerms& f) {
    return {static_cast<int>(f.lower.size()), static_cast<int>(f.jacobian.cols()) + 2};
  }
  static void Flatten(const sot::TaskTerms& f, double* out) {
    const Eigen::Index k = f.lower.size(), nv = f.jacobian.cols();
    Eigen::Map<Eigen::MatrixXd>(out, k, nv) = f.jacobian;
    Eigen::Map<Eigen::VectorXd>(out + k * nv, k) = f.lower;
    Eigen::Map<Eigen::VectorXd>(out + k * (nv + 1), k) = f.upper;
  }
  static void Unflatten(const double* in, sot::TaskTerms* f) {
    const Eigen::Index k = f->lower.size(), nv = f->jacobian.cols();
    f->jacobian = Eigen::Map<const Eigen::MatrixXd>(in, k, nv);
    f->lower = Eigen::Map<const Eigen::VectorXd>(in + k * nv, k);
    f->upper = Eigen::Map<const Eigen::VectorXd>(in + k * (nv + 1), k);
  }
  static bool IsFinite(const sot::TaskTerms& f) {
    // Bounds may be ±infinity (unbounded rows), never NaN.
    return f.jacobian.allFinite() && !f.lower.hasNaN() && !f.upper.hasNaN();
  }
};

}  // namespace marionette::graph
