#include "marionette/graph/arithmetic.h"

namespace marionette::graph {

VectorConstant::VectorConstant(std::string name, const Eigen::VectorXd& value, bool settable)
    : Entity(std::move(name)) {
  value_ = &DeclareParameter<Eigen::VectorXd>("value", value, settable);
  out_ = &DeclareOutput<Eigen::VectorXd>("out", value, &VectorConstant::CalcOut, {value_});
}

void VectorConstant::CalcOut(const Tick& t, Eigen::VectorXd* out) const { *out = value_->Eval(t); }

VectorSum::VectorSum(std::string name, int n, int num_inputs) : Entity(std::move(name)) {
  if (n < 0 || num_inputs < 1) {
    throw GraphError("VectorSum '" + this->name() + "': needs n >= 0 and num_inputs >= 1");
  }
  std::vector<const SignalBase*> prerequisites;
  for (int i = 0; i < num_inputs; ++i) {
    ins_.push_back(
        &DeclareInput<Eigen::VectorXd>("in" + std::to_string(i), Eigen::VectorXd::Zero(n)));
    prerequisites.push_back(ins_.back());
  }
  out_ = &DeclareOutput<Eigen::VectorXd>("out", Eigen::VectorXd::Zero(n), &VectorSum::CalcOut,
                                         prerequisites);
}

void VectorSum::CalcOut(const Tick& t, Eigen::VectorXd* out) const {
  *out = ins_[0]->Eval(t);
  for (size_t i = 1; i < ins_.size(); ++i) *out += ins_[i]->Eval(t);
}

VectorGain::VectorGain(std::string name, int n, double gain) : Entity(std::move(name)) {
  in_ = &DeclareInput<Eigen::VectorXd>("in", Eigen::VectorXd::Zero(n));
  gain_ = &DeclareParameter<double>("gain", gain);
  out_ = &DeclareOutput<Eigen::VectorXd>("out", Eigen::VectorXd::Zero(n), &VectorGain::CalcOut,
                                         {in_, gain_});
}

void VectorGain::CalcOut(const Tick& t, Eigen::VectorXd* out) const {
  *out = gain_->Eval(t) * in_->Eval(t);
}

MatrixVectorProduct::MatrixVectorProduct(std::string name, int rows, int cols)
    : Entity(std::move(name)) {
  matrix_ = &DeclareInput<Eigen::MatrixXd>("matrix", Eigen::MatrixXd::Zero(rows, cols));
  vector_ = &DeclareInput<Eigen::VectorXd>("vector", Eigen::VectorXd::Zero(cols));
  out_ = &DeclareOutput<Eigen::VectorXd>("out", Eigen::VectorXd::Zero(rows),
                                         &MatrixVectorProduct::CalcOut, {matrix_, vector_});
}

void MatrixVectorProduct::CalcOut(const Tick& t, Eigen::VectorXd* out) const {
  out->noalias() = matrix_->Eval(t) * vector_->Eval(t);
}

VectorIntegrator::VectorIntegrator(std::string name, const Eigen::VectorXd& initial)
    : Entity(std::move(name)) {
  derivative_ = &DeclareInput<Eigen::VectorXd>("derivative", Eigen::VectorXd::Zero(initial.size()));
  state_ = &DeclareState<Eigen::VectorXd>("state", initial, &VectorIntegrator::UpdateState,
                                          {derivative_});
}

void VectorIntegrator::UpdateState(const Tick& t, const Eigen::VectorXd& x,
                                   Eigen::VectorXd* next) const {
  *next = x + t.dt * derivative_->Eval(t);
}

}  // namespace marionette::graph
