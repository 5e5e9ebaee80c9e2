#pragma once
/// MeasuredBase: the configuration the controller computes its kinematics at, as the Stack of
/// Tasks does on a real robot: the joints at their commanded positions (the integrated command,
/// which the stiff joint servos track) and the floating base where it is measured (here the
/// simulator's ground truth; an estimator on a real robot).
/// @entity  inputs: q_command (nq), q_measured (nq)   outputs: q (nq)

#include <Eigen/Core>
#include <string>

#include "marionette/graph/entity.h"

namespace marionette::controller {

class MeasuredBase final : public graph::Entity {
 public:
  /// `base_nq` = the number of leading configuration entries of the base joint (7 for a free
  /// flyer, 4 for a planar base, 0 for a fixed base); `nq` the full size.
  MeasuredBase(std::string name, int nq, int base_nq);
  const char* type_name() const override { return "MeasuredBase"; }

  graph::InputSignal<Eigen::VectorXd>& q_command_input() { return *q_command_; }
  graph::InputSignal<Eigen::VectorXd>& q_measured_input() { return *q_measured_; }
  graph::OutputSignal<Eigen::VectorXd>& q_output() { return *q_; }

 private:
  void CalcQ(const graph::Tick& t, Eigen::VectorXd* q) const;
  int base_nq_;
  graph::InputSignal<Eigen::VectorXd>* q_command_{};
  graph::InputSignal<Eigen::VectorXd>* q_measured_{};
  graph::OutputSignal<Eigen::VectorXd>* q_{};
};

}  // namespace marionette::controller
