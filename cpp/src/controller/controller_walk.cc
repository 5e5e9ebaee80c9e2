// marionette-controller's walking edges (Dang 2012 §2.6.3): FOOTSTEP_PLAN in (LCM thread: decoded,
// validated, posted to the active controller's footstep manager), WALK_STATUS out (the loop copies
// the walk's state into the snapshot, the publisher sends it with ROBOT_STATE).
#include "controller_impl.h"
#include "marionette/lcmt_footstep_plan.hpp"
#include "marionette/lcmt_walk_status.hpp"
#include "marionette/walk/support_polygon.h"

namespace marionette::controller {

void Controller::Impl::OnFootstepPlan(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  Guarded(channels::kFootstepPlan, [&] { ReceiveFootstepPlan(rbuf); });
}

void Controller::Impl::ReceiveFootstepPlan(const lcm::ReceiveBuffer* rbuf) {
  lcmt_footstep_plan msg;
  if (!Admit(channels::kFootstepPlan, rbuf, &msg)) return;
  const std::string which = "plan " + std::to_string(msg.plan_id);
  auto it = controllers.find(active_owned_id);
  walk::FootstepManager* steps = it == controllers.end() ? nullptr : it->second->walk_steps;
  if (steps == nullptr) {
    Reject(channels::kFootstepPlan, "no walking controller",
           which +
               ": the active controller has no walk: tasks (walk:left_foot, walk:right_foot, "
               "walk:com, walk:waist)");
    return;
  }
  if (msg.num_steps != static_cast<int>(msg.steps.size()) ||
      msg.num_steps > walk::FootstepPlan::kMaxSteps) {
    Reject(channels::kFootstepPlan, "wrong size",
           which + ": " + std::to_string(msg.num_steps) + " steps (at most " +
               std::to_string(walk::FootstepPlan::kMaxSteps) + ", arrays must match num_steps)");
    return;
  }
  auto plan = std::make_unique<walk::FootstepPlan>();  // ~10 kB: off the LCM thread's stack
  plan->plan_id = msg.plan_id;
  plan->first_step_index = msg.first_step_index;
  plan->stop_at_end = msg.stop_at_end;
  plan->num_steps = msg.num_steps;
  plan->source_hash = Fnv1a(rbuf->data, rbuf->data_size);
  for (int k = 0; k < msg.num_steps; ++k) {
    const lcmt_footstep& m = msg.steps[k];
    walk::Footstep& s = plan->steps[k];
    if (m.num_via != static_cast<int>(m.via.size()) || m.num_via > walk::SwingFoot::kMaxVia) {
      Reject(channels::kFootstepPlan, "wrong size",
             which + ", step " + std::to_string(k) + ": " + std::to_string(m.num_via) +
                 " via points (at most " + std::to_string(walk::SwingFoot::kMaxVia) + ")");
      return;
    }
    s.index = m.index;
    s.is_left = m.is_left;
    s.placement << m.x, m.y, m.z, m.yaw;
    s.single_support = m.duration;
    s.double_support = m.double_support;
    s.step_height = m.step_height;
    s.num_via = m.num_via;
    for (int i = 0; i < m.num_via; ++i) s.via[i] << m.via[i][0], m.via[i][1], m.via[i][2];
  }
  const std::string problem = walk::ValidateFootstepPlan(*plan);
  if (!problem.empty()) {
    Reject(channels::kFootstepPlan, "invalid plan", which + ": " + problem);
    return;
  }
  // Posted even to a hold controller's stopped walk, which refuses it at its next tick: the
  // plan is then journaled as consumed at the same tick live and in a replay.
  if (active_owned_id == kHoldControllerId) {
    Reject(channels::kFootstepPlan, "holding",
           which + ": the hold controller ends the walk after the current step");
  }
  if (!steps->Post(*plan)) Reject(channels::kFootstepPlan, "queue full", which + " dropped");
}

void Controller::Impl::FillWalkStatus(const graph::Tick& t, Snapshot* s) {
  walk::FootstepManager& steps = *active->walk_steps;
  s->walk_plan_id = steps.plan_id_output().Eval(t);
  s->walk_step_index = steps.step_index_output().Eval(t);
  s->walk_phase = steps.phase_output().Eval(t);
  s->walk_phase_progress = steps.phase_progress_output().Eval(t);
  s->walk_num_queued = steps.num_queued();
  const Eigen::VectorXd& com = active->walk_pattern->com_output().Eval(t);
  const Eigen::VectorXd& zmp = steps.zmp_reference_output().Eval(t);
  for (int k = 0; k < 3; ++k) s->walk_com[k] = com[k];
  for (int k = 0; k < 2; ++k) s->walk_zmp_reference[k] = zmp[k];
  const walk::FootPlacement left = walk::PoseToPlacement(steps.left_foot_output().Eval(t));
  const walk::FootPlacement right = walk::PoseToPlacement(steps.right_foot_output().Eval(t));
  for (int k = 0; k < 4; ++k) s->walk_left[k] = left[k], s->walk_right[k] = right[k];
  // Measured ZMP (eq. 2.40-2.46) from the soles' wrenches about their origins; NaN without
  // force sensing (kinematic backend) or load.
  s->walk_zmp_measured = {std::nan(""), std::nan("")};
  if (device == nullptr) return;
  const sot::Kinematics& k = robot_model->kinematics_output().Eval(t);
  std::array<walk::SoleWrench, 4> wrenches;
  const int n =
      std::min<int>(static_cast<int>(contact_frames.size()), static_cast<int>(wrenches.size()));
  double ground = std::numeric_limits<double>::infinity();
  for (int i = 0; i < n; ++i) {
    const Eigen::VectorXd& w = device->wrench_output(i).value();
    wrenches[i].origin = k.placement(contact_frames[i]).translation();
    wrenches[i].force = w.head<3>();
    wrenches[i].torque = w.tail<3>();
    if (w[2] > 10.0) ground = std::min(ground, wrenches[i].origin.z());
  }
  Eigen::Vector2d p;
  if (std::isfinite(ground) && walk::MeasuredZmp(wrenches.data(), n, ground, &p)) {
    s->walk_zmp_measured = {p.x(), p.y()};
  }
}

void Controller::Impl::PublishWalkStatus(const Snapshot& s) {
  lcmt_walk_status msg;
  msg.utime = s.utime;
  msg.plan_id = s.walk_plan_id;
  msg.current_step_index = s.walk_step_index;
  msg.num_steps = s.walk_num_queued;
  msg.phase = walk::ToString(static_cast<walk::WalkPhase>(s.walk_phase));
  msg.phase_progress = s.walk_phase_progress;
  for (int k = 0; k < 3; ++k) msg.com[k] = s.walk_com[k];
  for (int k = 0; k < 2; ++k)
    msg.zmp_reference[k] = s.walk_zmp_reference[k], msg.zmp_measured[k] = s.walk_zmp_measured[k];
  for (int k = 0; k < 4; ++k)
    msg.left_foot[k] = s.walk_left[k], msg.right_foot[k] = s.walk_right[k];
  lcm.publish(channels::kWalkStatus, &msg);
}

}  // namespace marionette::controller
