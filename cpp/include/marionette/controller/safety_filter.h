#pragma once
/// SafetyFilter: the last entity before the robot (ros_control's role of checking and limiting
/// commands, Agimus §3.3.5). The solver's velocity goes through it:
///   - mode hold or estop → zero velocity (the position command freezes, the servos hold);
///   - any non-finite entry → zero velocity for this tick, counted;
///   - each 1-dof joint velocity clamped to its velocity limit and so that q + v dt stays within
///     the position limits (a joint outside its limits may only move back inside).
/// @entity  inputs: velocity (nv), q (nq), mode (int parameter: 0 run, 1 hold, 2 estop)
///          outputs: command (nv, the filtered velocity), num_clamped (int, joints clamped this
///          tick),
///                   non_finite (bool, the input was rejected this tick)

#include <Eigen/Core>
#include <pinocchio/multibody/model.hpp>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"

namespace marionette::controller {

enum class ControlMode : int { kRun = 0, kHold = 1, kEstop = 2 };

class SafetyFilter final : public graph::Entity {
 public:
  /// Limits from `model` (position limits and upperVelocityLimit of its 1-dof joints), scaled by
  /// `velocity_scale` (<= 1), for the control period `dt`.
  SafetyFilter(std::string name, const pinocchio::Model& model, double dt,
               double velocity_scale = 1.0);
  const char* type_name() const override { return "SafetyFilter"; }

  graph::InputSignal<Eigen::VectorXd>& velocity_input() { return *velocity_in_; }
  graph::InputSignal<Eigen::VectorXd>& q_input() { return *q_; }
  graph::InputSignal<int>& mode_input() { return *mode_; }
  graph::OutputSignal<Eigen::VectorXd>& velocity_output() { return *velocity_out_; }
  graph::OutputSignal<int>& num_clamped_output() { return *num_clamped_; }
  graph::OutputSignal<bool>& non_finite_output() { return *non_finite_; }

 private:
  struct Limit {
    int idx_q, idx_v;
    double lower, upper, max_velocity;
  };
  void CalcVelocity(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcNumClamped(const graph::Tick& t, int* out) const;
  void CalcNonFinite(const graph::Tick& t, bool* out) const;

  double dt_;
  std::vector<Limit> limits_;
  graph::InputSignal<Eigen::VectorXd>* velocity_in_{};
  graph::InputSignal<Eigen::VectorXd>* q_{};
  graph::InputSignal<int>* mode_{};
  graph::OutputSignal<Eigen::VectorXd>* velocity_out_{};
  graph::OutputSignal<int>* num_clamped_{};
  graph::OutputSignal<bool>* non_finite_{};
};

}  // namespace marionette::controller
