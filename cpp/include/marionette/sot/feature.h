#pragma once
/// Features: a task function's error e(q, t) = s(q) − s*(t) and its derivatives (Nicolin 2022
/// §3.2.4.1, Definition 8):
///   error     e (k)
///   jacobian  J = ∂e/∂q (k x nv), acting on tangent vectors: ė = J v + ∂e/∂t
///   drift     ∂e/∂t (k), the error rate with the robot still (a moving reference)
/// k = the number of components kept by the feature's mask. A Task turns these into a desired
/// joint-space equation; the Solver stacks tasks.
///
/// Every feature has the input `kinematics` (plug RobotModel.kinematics) plus its own reference
/// inputs, and the outputs `terms` (all three, what a Task reads), `error` and `jacobian`
/// (copies for introspection and tracing, computed only when pulled).

#include <Eigen/Core>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"
#include "marionette/sot/kinematics.h"

namespace marionette::sot {

struct FeatureTerms {
  FeatureTerms() = default;
  FeatureTerms(int k, int nv)
      : error(Eigen::VectorXd::Zero(k)),
        jacobian(Eigen::MatrixXd::Zero(k, nv)),
        drift(Eigen::VectorXd::Zero(k)) {}
  Eigen::VectorXd error;     ///< e (k)
  Eigen::MatrixXd jacobian;  ///< ∂e/∂q (k x nv)
  Eigen::VectorXd drift;     ///< ∂e/∂t (k)
};

/// Base of all features. A subclass declares its inputs, computes its full (unmasked) terms in
/// ComputeFull, and calls DeclareTermsOutput at the end of its constructor.
class Feature : public graph::Entity {
 public:
  graph::InputSignal<Kinematics>& kinematics_input() { return *kinematics_; }
  graph::OutputSignal<FeatureTerms>& terms_output() { return *terms_; }
  graph::OutputSignal<Eigen::VectorXd>& error_output() { return *error_; }
  graph::OutputSignal<Eigen::MatrixXd>& jacobian_output() { return *jacobian_; }

  int dimension() const { return static_cast<int>(kept_.size()); }  ///< k
  int full_dimension() const { return full_dimension_; }
  const std::vector<int>& kept_components() const { return kept_; }
  int nv() const { return model_->nv; }
  const ModelPtr& model() const { return model_; }
  /// When not empty, the Jacobian is constant and row i is the unit row e_{unit_columns()[i]}^T
  /// (posture, joint limits): the solver uses it to skip products and clamp boxes.
  const std::vector<int>& unit_columns() const { return unit_columns_; }

 protected:
  /// `full_dimension` = number of components before masking (6 for a pose, 3 for a point...).
  Feature(std::string name, ModelPtr model, int full_dimension, const Mask& mask);

  /// Declares the outputs; `prerequisites` are the subclass's inputs (kinematics is added).
  void DeclareTermsOutput(std::vector<const graph::SignalBase*> prerequisites);
  /// Declares J as constant unit rows (call before DeclareTermsOutput): full component i of the
  /// error moves with tangent index columns[i] only, with coefficient 1.
  void SetUnitJacobian(const std::vector<int>& columns);

  /// Writes the full (unmasked) terms: error (full_dimension), jacobian (full_dimension x nv),
  /// drift. Must not allocate. `full` keeps its values between calls (constant Jacobian
  /// entries may be written once).
  virtual void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                           FeatureTerms* full) const = 0;

  /// Prefix for error messages: "FeatureSE3 'name'".
  std::string who() const { return std::string(type_name()) + " '" + name() + "'"; }

  ModelPtr model_;
  graph::InputSignal<Kinematics>* kinematics_{};

 private:
  void CalcTerms(const graph::Tick& t, FeatureTerms* out) const;
  void CalcError(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcJacobian(const graph::Tick& t, Eigen::MatrixXd* out) const;

  int full_dimension_;
  std::vector<int> kept_;
  bool masked_;
  std::vector<int> unit_columns_;
  std::vector<int> full_unit_columns_;
  // Scratch for masked features (no information kept across ticks; the constant Jacobian
  // entries of unit-Jacobian features are written once at construction).
  mutable FeatureTerms full_;
  graph::OutputSignal<FeatureTerms>* terms_{};
  graph::OutputSignal<Eigen::VectorXd>* error_{};
  graph::OutputSignal<Eigen::MatrixXd>* jacobian_{};
};

/// Checks a vector's size for a constructor argument; throws SotError naming `who` and `what`.
void CheckSize(const Eigen::Ref<const Eigen::VectorXd>& v, int expected, const std::string& who,
               const char* what);

}  // namespace marionette::sot

namespace marionette::graph {

/// FeatureTerms flatten to a k x (nv + 2) matrix [J | e | ∂e/∂t] (column-major).
template <>
struct ValueTraits<sot::FeatureTerms> {
  static constexpr const char* kName = "feature_terms";
  static Shape ShapeOf(const sot::FeatureTerms& f) {
    return {static_cast<int>(f.error.size()), static_cast<int>(f.jacobian.cols()) + 2};
  }
  static void Flatten(const sot::FeatureTerms& f, double* out) {
    const Eigen::Index k = f.error.size(), nv = f.jacobian.cols();
    Eigen::Map<Eigen::MatrixXd>(out, k, nv) = f.jacobian;
    Eigen::Map<Eigen::VectorXd>(out + k * nv, k) = f.error;
    Eigen::Map<Eigen::VectorXd>(out + k * (nv + 1), k) = f.drift;
  }
  static void Unflatten(const double* in, sot::FeatureTerms* f) {
    const Eigen::Index k = f->error.size(), nv = f->jacobian.cols();
    f->jacobian = Eigen::Map<const Eigen::MatrixXd>(in, k, nv);
    f->error = Eigen::Map<const Eigen::VectorXd>(in + k * nv, k);
    f->drift = Eigen::Map<const Eigen::VectorXd>(in + k * (nv + 1), k);
  }
  static bool IsFinite(const sot::FeatureTerms& f) {
    return f.error.allFinite() && f.jacobian.allFinite() && f.drift.allFinite();
  }
};

}  // namespace marionette::graph
