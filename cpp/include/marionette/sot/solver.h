#pragma once
/// Solver: the strict hierarchy of a stack of tasks as an entity (SoT's Sot entity).
///
/// Constructed with its levels (Drake style: its task inputs are plugged at construction, the
/// tasks must be added to the same graph). Level 0 has the highest priority; tasks sharing a
/// level are stacked. Put the joint-limit task (AddJointLimits) at level 0 to make the bounds
/// hard for every level. See hierarchy.h for the algorithm.
///
/// Smooth switching (Dang 2012 eq. 2.26–2.34): when the set of active tasks changes at tick τ
/// (a task's `active` input toggled), and at this solver's first tick, each equality task's
/// target b_i = J_i v (its desired -λe - ∂e/∂t) is blended from the task's velocity under the
/// previous command v(τ⁻) (eq. 2.26–2.28):
///   b̃_i(t) = b_i(t) + exp(-(t - τ)/T) (J_i(τ) v(τ⁻) - b_i(τ))
/// and what the new stack still cannot reproduce of v(τ⁻) is blended in joint space (eq. 2.34):
///   v(t) = v_stack(t) + exp(-(t - τ)/T) (v(τ⁻) - v_stack(τ)).
/// So v is continuous at τ, every level keeps its priority during the blend (the joint-space
/// residual lies in the null space of all equality tasks unless a bound binds), and v reaches
/// the new stack's solution with time constant T (switch_time_constant). v(τ⁻) is the previous
/// command, or at the first tick the initial_velocity input (plug a device's applied velocity
/// to swap solvers with a GraphEdit without a jump; the default 0 starts from rest). Box bounds
/// of level-0 inequality tasks (joint limits) are enforced on v by clamping.
/// @entity  inputs: task_<name> for every task (plugged), initial_velocity (nv, default 0)
///          outputs: velocity (nv, the command), stack_velocity (nv, the hierarchy's solution
///          with blended targets), unblended_velocity (nv, the hierarchy's solution with the
///          tasks' own targets: where the blend converges; computed only when pulled, e.g. by a
///          controller's start check), target_offsets (all task rows), joint_offset (nv), switching
///          states: previous_velocity (nv), target_offset_state, joint_offset_state (nv),
///          activity (one entry per task)

#include <Eigen/Core>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"
#include "marionette/sot/hierarchy.h"
#include "marionette/sot/task.h"

namespace marionette::sot {

struct SolverOptions {
  HierarchyOptions hierarchy;
  double switch_time_constant = 0.05;  ///< T [s] of the blend; 0 = no blending
};

class Solver final : public graph::Entity {
 public:
  using Levels = std::vector<std::vector<Task*>>;
  /// Throws SotError on an empty stack, a null task, the same task twice, or tasks of another nv.
  Solver(std::string name, int nv, Levels levels, SolverOptions options = {});
  const char* type_name() const override { return "Solver"; }

  graph::OutputSignal<Eigen::VectorXd>& velocity_output() { return *velocity_; }
  graph::OutputSignal<Eigen::VectorXd>& stack_velocity_output() { return *stack_velocity_; }
  graph::OutputSignal<Eigen::VectorXd>& unblended_velocity_output() { return *unblended_velocity_; }
  graph::InputSignal<Eigen::VectorXd>& initial_velocity_input() { return *initial_velocity_; }
  graph::OutputSignal<Eigen::VectorXd>& joint_offset_output() { return *joint_offset_; }
  graph::OutputSignal<Eigen::VectorXd>& target_offsets_output() { return *target_offsets_; }
  graph::OutputSignal<bool>& switching_output() { return *switching_; }
  const Levels& levels() const { return levels_; }
  const Hierarchy& hierarchy() const { return hierarchy_; }
  /// Ranks, QP use and damping of the last solve.
  const HierarchyReport& report() const { return workspace_.report(); }
  int nv() const { return nv_; }

 private:
  void CalcSwitching(const graph::Tick& t, bool* out) const;
  void CalcTargetOffsets(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcStackVelocity(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcUnblendedVelocity(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcJointOffset(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcVelocity(const graph::Tick& t, Eigen::VectorXd* out) const;
  // Box bounds of level-0 inequality tasks (joint limits) enforced on v by clamping.
  void ClampToHardBoxes(const graph::Tick& t, Eigen::VectorXd* v) const;
  void UpdatePrevious(const graph::Tick& t, const Eigen::VectorXd& x, Eigen::VectorXd* next) const;
  void UpdateTargetOffsets(const graph::Tick& t, const Eigen::VectorXd& x,
                           Eigen::VectorXd* next) const;
  void UpdateJointOffset(const graph::Tick& t, const Eigen::VectorXd& x,
                         Eigen::VectorXd* next) const;
  void UpdateActivity(const graph::Tick& t, const Eigen::VectorXd& x, Eigen::VectorXd* next) const;
  // v(τ⁻): the previous command, or initial_velocity at the first tick.
  const Eigen::VectorXd& VelocityBefore(const graph::Tick& t) const;
  double Decay(const graph::Tick& t) const;

  int nv_;
  Levels levels_;
  SolverOptions options_;
  Hierarchy hierarchy_;
  std::vector<graph::InputSignal<TaskTerms>*> task_inputs_;  // level order
  std::vector<int> hard_box_tasks_;                          // level-0 unit-row inequality tasks
  graph::InputSignal<Eigen::VectorXd>* initial_velocity_{};
  graph::OutputSignal<Eigen::VectorXd>* stack_velocity_{};
  graph::OutputSignal<Eigen::VectorXd>* unblended_velocity_{};
  graph::OutputSignal<Eigen::VectorXd>* velocity_{};
  graph::OutputSignal<bool>* switching_{};
  graph::OutputSignal<Eigen::VectorXd>* target_offsets_{};
  graph::OutputSignal<Eigen::VectorXd>* joint_offset_{};
  graph::OutputSignal<Eigen::VectorXd>* previous_{};
  graph::OutputSignal<Eigen::VectorXd>* target_offset_state_{};
  graph::OutputSignal<Eigen::VectorXd>* joint_offset_state_{};
  graph::OutputSignal<Eigen::VectorXd>* activity_{};
  std::vector<int> first_rows_;  // first row of each task among all rows
  // Scratch (no information kept across ticks beyond the report of the last solve).
  mutable HierarchyWorkspace workspace_;
  mutable std::vector<const TaskTerms*> terms_;
};

}  // namespace marionette::sot
