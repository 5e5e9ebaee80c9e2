#include "marionette/walk/footstep_manager.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "marionette/walk/swing_foot.h"

namespace marionette::walk {
namespace {

constexpr double kTimeEpsilon = 1e-9;  // [s] ticks land on phase boundaries up to rounding

// Halfway between two feet's yaws the short way round (feet never differ by half a turn).
double MeanYaw(const FootPlacement& a, const FootPlacement& b) {
  return a[3] + 0.5 * WrapAngle(b[3] - a[3]);
}

Eigen::Vector2d Middle(const FootPlacement& a, const FootPlacement& b) {
  return 0.5 * (a.head<2>() + b.head<2>());
}

}  // namespace

const char* ToString(WalkPhase phase) {
  switch (phase) {
    case WalkPhase::kStanding:
      return "standing";
    case WalkPhase::kDoubleSupport:
      return "double_support";
    case WalkPhase::kLeftSwing:
      return "left_swing";
    case WalkPhase::kRightSwing:
      return "right_swing";
  }
  return "unknown";
}

void FootstepManagerOptions::Check() const {
  if (!(dt > 0.0 && dt <= 0.1))
    throw std::invalid_argument("FootstepManagerOptions: dt must be in (0, 0.1] s");
  if (preview_samples < 1 || preview_samples > 100000) {
    throw std::invalid_argument("FootstepManagerOptions: preview_samples must be in [1, 100000]");
  }
  if (!(final_double_support > 0.0 && final_double_support <= 10.0)) {
    throw std::invalid_argument(
        "FootstepManagerOptions: final_double_support must be in (0, 10] s");
  }
  if (!(min_first_double_support >= 0.0 && min_first_double_support <= 10.0)) {
    throw std::invalid_argument(
        "FootstepManagerOptions: min_first_double_support must be in [0, 10] s");
  }
  if (!(start_delay < 60.0))
    throw std::invalid_argument("FootstepManagerOptions: start_delay must be < 60 s");
  if (mailbox_capacity < 1)
    throw std::invalid_argument("FootstepManagerOptions: mailbox_capacity must be >= 1");
}

FootstepManager::FootstepManager(std::string name, const FootPlacement& left,
                                 const FootPlacement& right, const Eigen::Vector2d& rest_zmp,
                                 FootstepManagerOptions options)
    : Entity(std::move(name)),
      options_((options.Check(), options)),
      mailbox_(options.mailbox_capacity, FootstepPlan{}) {
  if (!left.allFinite() || !right.allFinite() || !rest_zmp.allFinite()) {
    throw std::invalid_argument("FootstepManager '" + this->name() +
                                "': non-finite initial feet or ZMP");
  }
  const Eigen::VectorXd zero6 = Eigen::VectorXd::Zero(6);
  left_foot_ = &DeclareOutput<pinocchio::SE3>("left_foot", PlacementToPose(left),
                                              &FootstepManager::CalcLeftFoot, {});
  right_foot_ = &DeclareOutput<pinocchio::SE3>("right_foot", PlacementToPose(right),
                                               &FootstepManager::CalcRightFoot, {});
  left_velocity_ = &DeclareOutput<Eigen::VectorXd>("left_foot_velocity", zero6,
                                                   &FootstepManager::CalcLeftVelocity, {});
  right_velocity_ = &DeclareOutput<Eigen::VectorXd>("right_foot_velocity", zero6,
                                                    &FootstepManager::CalcRightVelocity, {});
  waist_ = &DeclareOutput<pinocchio::SE3>("waist", pinocchio::SE3::Identity(),
                                          &FootstepManager::CalcWaist, {left_foot_, right_foot_});
  waist_velocity_ =
      &DeclareOutput<Eigen::VectorXd>("waist_velocity", zero6, &FootstepManager::CalcWaistVelocity,
                                      {left_velocity_, right_velocity_});
  zmp_window_ = &DeclareOutput<Eigen::MatrixXd>(
      "zmp_window", Eigen::MatrixXd::Zero(2, options_.preview_samples + 1),
      &FootstepManager::CalcZmpWindow, {});
  zmp_reference_ = &DeclareOutput<Eigen::VectorXd>("zmp_reference", Eigen::VectorXd::Zero(2),
                                                   &FootstepManager::CalcZmpReference, {});
  phase_ = &DeclareOutput<int>("phase", 0, &FootstepManager::CalcPhase, {});
  phase_progress_ =
      &DeclareOutput<double>("phase_progress", 0.0, &FootstepManager::CalcPhaseProgress, {});
  step_index_ = &DeclareOutput<int>("step_index", -1, &FootstepManager::CalcStepIndex, {});
  support_ = &DeclareOutput<int>("support", 3, &FootstepManager::CalcSupport, {});
  plan_id_ = &DeclareOutput<int>("plan_id", 0, &FootstepManager::CalcPlanId, {});
  DeclarePoll("apply_plans", &FootstepManager::Poll);
  Reset(left, right, rest_zmp);
}

bool FootstepManager::Post(const FootstepPlan& plan) {
  if (mailbox_.Push(plan)) return true;
  dropped_plans_.fetch_add(1);
  return false;
}

void FootstepManager::Reset(const FootPlacement& left, const FootPlacement& right,
                            const Eigen::Vector2d& rest_zmp) {
  mode_ = Mode::kStanding;
  queue_size_ = 0;
  feet_[kLeft] = left;
  feet_[kRight] = right;
  rest_zmp_ = rest_zmp;
  previous_zmp_ = rest_zmp;
  phase_start_ = 0.0;
  stopped_ = false;
  RebuildSegments();
}

void FootstepManager::HoldWaist(const Eigen::Matrix3d& R_waist) {
  const double mean = MeanYaw(feet_[kLeft], feet_[kRight]);
  waist_offset_ = Eigen::AngleAxisd(-mean, Eigen::Vector3d::UnitZ()).toRotationMatrix() * R_waist;
}

void FootstepManager::StopAfterCurrentStep() {
  stopped_ = true;
  // Walking: the front step is in progress (from its double support on); stopping or standing:
  // whatever is queued has not started.
  const int keep = mode_ == Mode::kWalking ? std::min(queue_size_, 1) : 0;
  if (keep == queue_size_) return;
  queue_size_ = keep;
  RebuildSegments();
}

void FootstepManager::Poll(const graph::Tick& t) {
  bool changed = false;
  drained_count_ = 0;
  while (const FootstepPlan* plan = mailbox_.Front()) {
    if (drained_count_ < static_cast<int>(drained_hashes_.size()))
      drained_hashes_[drained_count_++] = plan->source_hash;
    ApplyPlan(*plan);
    mailbox_.PopFront();
    changed = true;
  }
  const Mode mode_before = mode_;
  const int queued_before = queue_size_;
  Advance(t.time);
  if (changed || mode_ != mode_before || queue_size_ != queued_before) RebuildSegments();
}

void FootstepManager::ApplyPlan(const FootstepPlan& plan) {
  if (stopped_) {
    ++refused_plans_;
    return;
  }
  if (queue_size_ == 0) {  // nothing started nor pending: a new walk, whatever its numbering
    queue_size_ = std::min(plan.num_steps, FootstepPlan::kMaxSteps);
    std::copy_n(plan.steps.begin(), queue_size_, queue_.begin());
  } else {
    // The step in progress (front, when walking) is never changed; queued steps from the
    // plan's first index on are replaced.
    const int locked = mode_ == Mode::kWalking ? queue_[0].index : queue_[0].index - 1;
    const int start = std::max(plan.first_step_index, locked + 1);
    int keep = 0;
    while (keep < queue_size_ && queue_[keep].index < start) ++keep;
    const int next_index = keep > 0 ? queue_[keep - 1].index + 1 : start;
    int from = 0;
    while (from < plan.num_steps && plan.steps[from].index < start) ++from;
    if (from < plan.num_steps && plan.steps[from].index != next_index) {  // a gap: refuse
      ++refused_plans_;
      return;
    }
    const int count = std::min(plan.num_steps - from, FootstepPlan::kMaxSteps - keep);
    std::copy_n(plan.steps.begin() + from, count, queue_.begin() + keep);
    queue_size_ = keep + count;
  }
  current_plan_id_ = plan.plan_id;
  ++applied_plans_;
}

void FootstepManager::Advance(double time) {
  for (;;) {
    if (mode_ == Mode::kWalking && time >= FrontEnd() - kTimeEpsilon) {
      const Footstep& done = queue_[0];
      const int moving = done.is_left ? kLeft : kRight;
      previous_zmp_ = feet_[1 - moving].head<2>();  // the support foot of the finished step
      phase_start_ = FrontEnd();
      feet_[moving] = done.placement;
      std::copy(queue_.begin() + 1, queue_.begin() + queue_size_, queue_.begin());
      --queue_size_;
      ++completed_steps_;
      if (queue_size_ == 0) mode_ = Mode::kStopping;
      continue;
    }
    if (mode_ == Mode::kStopping &&
        time >= phase_start_ + options_.final_double_support - kTimeEpsilon) {
      mode_ = Mode::kStanding;
      rest_zmp_ = Middle(feet_[kLeft], feet_[kRight]);
      continue;
    }
    if (mode_ == Mode::kStanding && queue_size_ > 0) {
      mode_ = Mode::kWalking;
      phase_start_ = time + options_.StartDelay();
      previous_zmp_ = rest_zmp_;
      queue_[0].double_support =
          std::max(queue_[0].double_support, options_.min_first_double_support);
      continue;
    }
    return;
  }
}

void FootstepManager::RebuildSegments() {
  num_segments_ = 0;
  const auto add = [this](double t0, double t1, const Eigen::Vector2d& p0,
                          const Eigen::Vector2d& p1) {
    if (num_segments_ < kMaxSegments) segments_[num_segments_++] = ZmpSegment{t0, t1, p0, p1};
  };
  std::array<FootPlacement, 2> feet = feet_;
  double time = phase_start_;
  Eigen::Vector2d previous = previous_zmp_;
  int first = 0;
  if (mode_ == Mode::kStanding) {
    final_zmp_ = rest_zmp_;
    return;
  }
  if (mode_ == Mode::kStopping) {
    const Eigen::Vector2d middle = Middle(feet[kLeft], feet[kRight]);
    add(time, time + options_.final_double_support, previous, middle);
    time += options_.final_double_support;
    previous = middle;
    if (queue_size_ == 0) {
      final_zmp_ = middle;
      return;
    }
    time += options_.StartDelay();  // the next walk starts from standing (Advance)
  }
  for (int k = first; k < queue_size_; ++k) {
    const Footstep& s = queue_[k];
    const int moving = s.is_left ? kLeft : kRight;
    const Eigen::Vector2d support = feet[1 - moving].head<2>();
    // A walk that starts after the final double support (plan received while stopping) gets
    // the same minimum first double support as one started from standing.
    const double ds = (mode_ == Mode::kStopping && k == 0)
                          ? std::max(s.double_support, options_.min_first_double_support)
                          : s.double_support;
    add(time, time + ds, previous, support);
    time += ds;
    add(time, time + s.single_support, support, support);
    time += s.single_support;
    feet[moving] = s.placement;
    previous = support;
  }
  const Eigen::Vector2d middle = Middle(feet[kLeft], feet[kRight]);
  add(time, time + options_.final_double_support, previous, middle);
  final_zmp_ = middle;
}

Eigen::Vector2d FootstepManager::ZmpAt(double time, int* hint) const {
  if (num_segments_ == 0) return final_zmp_;
  int k = std::max(0, *hint);
  while (k < num_segments_ && time >= segments_[k].t1) ++k;
  *hint = k;
  if (k >= num_segments_) return final_zmp_;
  const ZmpSegment& s = segments_[k];
  if (time <= s.t0) return s.p0;
  // Quintic blend between the two support points (continuous ZMP velocity and acceleration).
  const double sigma = QuinticBlend((time - s.t0) / std::max(s.t1 - s.t0, 1e-12)).value;
  return s.p0 + (s.p1 - s.p0) * sigma;
}

bool FootstepManager::Swinging(double time, int* side, FootSample* sample) const {
  if (mode_ != Mode::kWalking) return false;
  const double ss_start = FrontSingleSupportStart();
  if (time < ss_start) return false;
  const Footstep& s = queue_[0];
  *side = s.is_left ? kLeft : kRight;
  const SwingFoot swing(feet_[*side], s.placement, s.single_support, s.step_height, s.via.data(),
                        s.num_via);
  *sample = swing.Sample(time - ss_start);
  return true;
}

void FootstepManager::CalcFoot(const graph::Tick& t, int side, pinocchio::SE3* out) const {
  int swinging = -1;
  FootSample sample;
  if (Swinging(t.time, &swinging, &sample) && swinging == side) {
    *out = sample.pose;
  } else {
    *out = PlacementToPose(feet_[side]);
  }
}

void FootstepManager::CalcFootVelocity(const graph::Tick& t, int side, Eigen::VectorXd* out) const {
  int swinging = -1;
  FootSample sample;
  if (Swinging(t.time, &swinging, &sample) && swinging == side) {
    *out = sample.velocity;
  } else {
    out->setZero();
  }
}

void FootstepManager::CalcWaist(const graph::Tick& t, pinocchio::SE3* out) const {
  const FootPlacement l = PoseToPlacement(left_foot_->Eval(t));
  const FootPlacement r = PoseToPlacement(right_foot_->Eval(t));
  out->rotation(Eigen::AngleAxisd(MeanYaw(l, r), Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                waist_offset_);
  out->translation(0.5 * (l.head<3>() + r.head<3>()));
}

void FootstepManager::CalcWaistVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
  *out = 0.5 * (left_velocity_->Eval(t) + right_velocity_->Eval(t));
  out->segment<2>(3).setZero();  // it turns about the vertical only
}

void FootstepManager::CalcZmpWindow(const graph::Tick& t, Eigen::MatrixXd* out) const {
  int hint = 0;
  const double dt = options_.dt;
  for (Eigen::Index j = 0; j < out->cols(); ++j)
    out->col(j) = ZmpAt(t.time + static_cast<double>(j) * dt, &hint);
}

void FootstepManager::CalcZmpReference(const graph::Tick& t, Eigen::VectorXd* out) const {
  int hint = 0;
  *out = ZmpAt(t.time, &hint);
}

void FootstepManager::CalcPhase(const graph::Tick& t, int* out) const {
  if (mode_ == Mode::kStanding) {
    *out = static_cast<int>(WalkPhase::kStanding);
  } else if (mode_ == Mode::kStopping || t.time < FrontSingleSupportStart()) {
    *out = static_cast<int>(WalkPhase::kDoubleSupport);
  } else {
    *out = static_cast<int>(queue_[0].is_left ? WalkPhase::kLeftSwing : WalkPhase::kRightSwing);
  }
}

void FootstepManager::CalcPhaseProgress(const graph::Tick& t, double* out) const {
  double t0 = 0.0, t1 = 1.0;
  if (mode_ == Mode::kStanding) {
    *out = 0.0;
    return;
  }
  if (mode_ == Mode::kStopping) {
    t0 = phase_start_, t1 = phase_start_ + options_.final_double_support;
  } else if (t.time < FrontSingleSupportStart()) {
    t0 = phase_start_, t1 = FrontSingleSupportStart();
  } else {
    t0 = FrontSingleSupportStart(), t1 = FrontEnd();
  }
  *out = t1 > t0 ? std::clamp((t.time - t0) / (t1 - t0), 0.0, 1.0) : 1.0;
}

void FootstepManager::CalcStepIndex(const graph::Tick&, int* out) const {
  *out = mode_ == Mode::kWalking ? queue_[0].index : -1;
}

void FootstepManager::CalcSupport(const graph::Tick& t, int* out) const {
  int swinging = -1;
  FootSample sample;
  *out = Swinging(t.time, &swinging, &sample) ? (swinging == kLeft ? 2 : 1) : 3;
}

void FootstepManager::CalcPlanId(const graph::Tick&, int* out) const {
  *out = static_cast<int>(current_plan_id_);
}

}  // namespace marionette::walk
