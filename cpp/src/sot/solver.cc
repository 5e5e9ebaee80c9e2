#include "marionette/sot/solver.h"

#include <algorithm>
#include <cmath>
#include <set>

namespace marionette::sot {

namespace {

Hierarchy MakeHierarchy(int nv, const Solver::Levels& levels, const HierarchyOptions& options,
                        const std::string& who) {
  if (levels.empty()) throw SotError(who + ": no level");
  std::vector<std::vector<TaskShape>> shapes;
  std::set<const Task*> seen;
  for (size_t l = 0; l < levels.size(); ++l) {
    if (levels[l].empty()) throw SotError(who + ": level " + std::to_string(l) + " is empty");
    shapes.emplace_back();
    for (const Task* task : levels[l]) {
      if (task == nullptr) throw SotError(who + ": null task at level " + std::to_string(l));
      if (!seen.insert(task).second)
        throw SotError(who + ": task '" + task->name() + "' appears twice");
      if (task->nv() != nv) {
        throw SotError(who + ": task '" + task->name() + "' has nv " + std::to_string(task->nv()) +
                       ", the solver " + std::to_string(nv));
      }
      TaskShape shape;
      shape.rows = task->dimension();
      shape.inequality = task->inequality();
      shape.unit_columns = task->feature().unit_columns();
      shapes.back().push_back(std::move(shape));
    }
  }
  return Hierarchy(nv, std::move(shapes), options);
}

}  // namespace

Solver::Solver(std::string name, int nv, Levels levels, SolverOptions options)
    : Entity(std::move(name)),
      nv_(nv),
      levels_(std::move(levels)),
      options_(options),
      hierarchy_(MakeHierarchy(nv, levels_, options.hierarchy, "Solver '" + this->name() + "'")),
      workspace_(hierarchy_) {
  if (!(options_.switch_time_constant >= 0.0)) {
    throw SotError("Solver '" + this->name() + "': switch_time_constant must be >= 0");
  }
  std::vector<const graph::SignalBase*> task_signals;
  int rows = 0;
  for (size_t l = 0; l < levels_.size(); ++l) {
    for (Task* task : levels_[l]) {
      auto& in = DeclareInput<TaskTerms>("task_" + task->name(), task->terms_output().value());
      in.Plug(task->terms_output());
      task_inputs_.push_back(&in);
      task_signals.push_back(&in);
      first_rows_.push_back(rows);
      rows += task->dimension();
      if (l == 0 && task->inequality() && !task->feature().unit_columns().empty()) {
        hard_box_tasks_.push_back(static_cast<int>(task_inputs_.size()) - 1);
      }
    }
  }
  terms_.resize(task_inputs_.size());
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(nv_);
  const Eigen::VectorXd zero_rows = Eigen::VectorXd::Zero(rows);
  initial_velocity_ = &DeclareParameter<Eigen::VectorXd>("initial_velocity", zero);
  // States (x_t during tick t). The previous command and the offsets are written from this
  // tick's outputs, declared below. activity NaN = no tick yet: the first tick is a switch.
  previous_ =
      &DeclareState<Eigen::VectorXd>("previous_velocity", zero, &Solver::UpdatePrevious, {});
  target_offset_state_ = &DeclareState<Eigen::VectorXd>("target_offset_state", zero_rows,
                                                        &Solver::UpdateTargetOffsets, {});
  joint_offset_state_ =
      &DeclareState<Eigen::VectorXd>("joint_offset_state", zero, &Solver::UpdateJointOffset, {});
  activity_ = &DeclareState<Eigen::VectorXd>(
      "activity", Eigen::VectorXd::Constant(task_inputs_.size(), std::nan("")),
      &Solver::UpdateActivity, task_signals);
  std::vector<const graph::SignalBase*> switching_prerequisites = task_signals;
  switching_prerequisites.push_back(activity_);
  switching_ =
      &DeclareOutput<bool>("switching", false, &Solver::CalcSwitching, switching_prerequisites);
  std::vector<const graph::SignalBase*> offset_prerequisites = task_signals;
  offset_prerequisites.insert(offset_prerequisites.end(), {switching_, initial_velocity_, previous_,
                                                           activity_, target_offset_state_});
  target_offsets_ = &DeclareOutput<Eigen::VectorXd>(
      "target_offsets", zero_rows, &Solver::CalcTargetOffsets, offset_prerequisites);
  std::vector<const graph::SignalBase*> stack_prerequisites = task_signals;
  stack_prerequisites.push_back(target_offsets_);
  stack_velocity_ = &DeclareOutput<Eigen::VectorXd>(
      "stack_velocity", zero, &Solver::CalcStackVelocity, stack_prerequisites);
  unblended_velocity_ = &DeclareOutput<Eigen::VectorXd>(
      "unblended_velocity", zero, &Solver::CalcUnblendedVelocity, task_signals);
  joint_offset_ = &DeclareOutput<Eigen::VectorXd>(
      "joint_offset", zero, &Solver::CalcJointOffset,
      {switching_, stack_velocity_, initial_velocity_, previous_, activity_, joint_offset_state_});
  std::vector<const graph::SignalBase*> velocity_prerequisites = task_signals;
  velocity_prerequisites.insert(velocity_prerequisites.end(), {stack_velocity_, joint_offset_});
  velocity_ = &DeclareOutput<Eigen::VectorXd>("velocity", zero, &Solver::CalcVelocity,
                                              velocity_prerequisites);
}

void Solver::CalcSwitching(const graph::Tick& t, bool* out) const {
  const Eigen::VectorXd& activity = activity_->Eval(t);
  *out = false;
  for (size_t i = 0; i < task_inputs_.size(); ++i) {
    // NaN (first tick) differs from everything.
    if (activity[i] != (task_inputs_[i]->Eval(t).active ? 1.0 : 0.0)) *out = true;
  }
}

const Eigen::VectorXd& Solver::VelocityBefore(const graph::Tick& t) const {
  return std::isnan(activity_->Eval(t)[0]) ? initial_velocity_->Eval(t) : previous_->Eval(t);
}

double Solver::Decay(const graph::Tick& t) const {
  return std::exp(-t.dt / options_.switch_time_constant);
}

void Solver::CalcTargetOffsets(const graph::Tick& t, Eigen::VectorXd* out) const {
  if (options_.switch_time_constant == 0.0) {
    out->setZero();
    return;
  }
  if (!switching_->Eval(t)) {
    *out = target_offset_state_->Eval(t);
    return;
  }
  // Eq. 2.27: each task starts from the velocity the previous command gives it.
  const Eigen::VectorXd& v_before = VelocityBefore(t);
  out->setZero();
  for (size_t i = 0; i < task_inputs_.size(); ++i) {
    const TaskTerms& task = task_inputs_[i]->Eval(t);
    if (!task.active || task.inequality) continue;
    const Eigen::Index k = task.lower.size();
    out->segment(first_rows_[i], k).noalias() = task.jacobian * v_before;
    out->segment(first_rows_[i], k) -= task.lower;
  }
}

void Solver::CalcStackVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
  for (size_t i = 0; i < task_inputs_.size(); ++i) terms_[i] = &task_inputs_[i]->Eval(t);
  const Eigen::VectorXd& offsets = target_offsets_->Eval(t);
  SolveHierarchy(hierarchy_, terms_, &workspace_, out,
                 options_.switch_time_constant > 0.0 ? &offsets : nullptr);
}

void Solver::CalcUnblendedVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
  for (size_t i = 0; i < task_inputs_.size(); ++i) terms_[i] = &task_inputs_[i]->Eval(t);
  SolveHierarchy(hierarchy_, terms_, &workspace_, out, nullptr);
  ClampToHardBoxes(t, out);  // the same bounds as the command
}

void Solver::CalcJointOffset(const graph::Tick& t, Eigen::VectorXd* out) const {
  if (options_.switch_time_constant == 0.0) {
    out->setZero();
  } else if (switching_->Eval(t)) {
    *out = VelocityBefore(t) - stack_velocity_->Eval(t);  // eq. 2.34's residual
  } else {
    *out = joint_offset_state_->Eval(t);
  }
}

void Solver::CalcVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
  *out = stack_velocity_->Eval(t) + joint_offset_->Eval(t);
  ClampToHardBoxes(t, out);
}

void Solver::ClampToHardBoxes(const graph::Tick& t, Eigen::VectorXd* v) const {
  for (int i : hard_box_tasks_) {
    const TaskTerms& box = task_inputs_[i]->Eval(t);
    if (!box.active) continue;
    for (size_t j = 0; j < box.unit_columns.size(); ++j) {
      const int c = box.unit_columns[j];
      (*v)[c] = std::clamp((*v)[c], box.lower[j], std::max(box.lower[j], box.upper[j]));
    }
  }
}

void Solver::UpdatePrevious(const graph::Tick& t, const Eigen::VectorXd&,
                            Eigen::VectorXd* next) const {
  *next = velocity_->Eval(t);
}

void Solver::UpdateTargetOffsets(const graph::Tick& t, const Eigen::VectorXd&,
                                 Eigen::VectorXd* next) const {
  *next = target_offsets_->Eval(t);
  if (options_.switch_time_constant > 0.0) *next *= Decay(t);
}

void Solver::UpdateJointOffset(const graph::Tick& t, const Eigen::VectorXd&,
                               Eigen::VectorXd* next) const {
  *next = joint_offset_->Eval(t);
  if (options_.switch_time_constant > 0.0) *next *= Decay(t);
}

void Solver::UpdateActivity(const graph::Tick& t, const Eigen::VectorXd&,
                            Eigen::VectorXd* next) const {
  for (size_t i = 0; i < task_inputs_.size(); ++i) {
    (*next)[i] = task_inputs_[i]->Eval(t).active ? 1.0 : 0.0;
  }
}

}  // namespace marionette::sot
