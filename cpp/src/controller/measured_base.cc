#include "marionette/controller/measured_base.h"

namespace marionette::controller {

MeasuredBase::MeasuredBase(std::string name, int nq, int base_nq)
    : Entity(std::move(name)), base_nq_(base_nq) {
  if (base_nq_ < 0 || base_nq_ > nq) {
    throw graph::GraphError("MeasuredBase '" + this->name() + "': base size " +
                            std::to_string(base_nq) + " outside [0, " + std::to_string(nq) + "]");
  }
  q_command_ = &DeclareInput<Eigen::VectorXd>("q_command", Eigen::VectorXd::Zero(nq));
  q_measured_ = &DeclareInput<Eigen::VectorXd>("q_measured", Eigen::VectorXd::Zero(nq));
  q_ = &DeclareOutput<Eigen::VectorXd>("q", Eigen::VectorXd::Zero(nq), &MeasuredBase::CalcQ,
                                       {q_command_, q_measured_});
}

void MeasuredBase::CalcQ(const graph::Tick& t, Eigen::VectorXd* q) const {
  *q = q_command_->Eval(t);
  if (base_nq_ > 0) q->head(base_nq_) = q_measured_->Eval(t).head(base_nq_);
}

}  // namespace marionette::controller
