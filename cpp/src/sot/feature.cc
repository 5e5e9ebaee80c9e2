#include "marionette/sot/feature.h"

namespace marionette::sot {

Feature::Feature(std::string name, ModelPtr model, int full_dimension, const Mask& mask)
    : Entity(std::move(name)), model_(std::move(model)), full_dimension_(full_dimension) {
  if (!model_) throw SotError("feature '" + this->name() + "': null model");
  kept_ = MaskIndices(mask, full_dimension, "feature '" + this->name() + "'");
  masked_ = static_cast<int>(kept_.size()) != full_dimension;
  kinematics_ = &DeclareInput<Kinematics>("kinematics", Kinematics(model_));
}

void Feature::SetUnitJacobian(const std::vector<int>& columns) {
  full_unit_columns_ = columns;
  unit_columns_.clear();
  for (int i : kept_) unit_columns_.push_back(columns[i]);
}

void Feature::DeclareTermsOutput(std::vector<const graph::SignalBase*> prerequisites) {
  prerequisites.push_back(kinematics_);
  const int k = dimension();
  FeatureTerms model(k, nv());
  full_ = FeatureTerms(full_dimension_, nv());
  for (size_t i = 0; i < full_unit_columns_.size(); ++i)
    full_.jacobian(i, full_unit_columns_[i]) = 1.0;
  for (size_t i = 0; i < unit_columns_.size(); ++i) model.jacobian(i, unit_columns_[i]) = 1.0;
  terms_ = &DeclareOutput<FeatureTerms>("terms", model, &Feature::CalcTerms, prerequisites);
  error_ = &DeclareOutput<Eigen::VectorXd>("error", Eigen::VectorXd::Zero(k), &Feature::CalcError,
                                           {terms_});
  jacobian_ = &DeclareOutput<Eigen::MatrixXd>("jacobian", Eigen::MatrixXd::Zero(k, nv()),
                                              &Feature::CalcJacobian, {terms_});
}

void Feature::CalcTerms(const graph::Tick& t, FeatureTerms* out) const {
  const Kinematics& kinematics = kinematics_->Eval(t);
  if (!masked_) {
    ComputeFull(t, kinematics, out);
    return;
  }
  ComputeFull(t, kinematics, &full_);
  for (int i = 0; i < dimension(); ++i) {
    out->error[i] = full_.error[kept_[i]];
    out->drift[i] = full_.drift[kept_[i]];
    out->jacobian.row(i) = full_.jacobian.row(kept_[i]);
  }
}

void Feature::CalcError(const graph::Tick& t, Eigen::VectorXd* out) const {
  *out = terms_->Eval(t).error;
}

void Feature::CalcJacobian(const graph::Tick& t, Eigen::MatrixXd* out) const {
  *out = terms_->Eval(t).jacobian;
}

void CheckSize(const Eigen::Ref<const Eigen::VectorXd>& v, int expected, const std::string& who,
               const char* what) {
  if (v.size() != expected) {
    throw SotError(who + ": " + what + " has " + std::to_string(v.size()) + " entries, expected " +
                   std::to_string(expected));
  }
}

}  // namespace marionette::sot
