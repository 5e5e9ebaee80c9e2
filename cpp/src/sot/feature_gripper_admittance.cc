#include "marionette/sot/feature_gripper_admittance.h"

#include <algorithm>
#include <cmath>

#include <pinocchio/algorithm/joint-configuration.hpp>

namespace marionette::sot {
namespace {

// Indices of the machine state (phase, y, r, primed, ṙ, elapsed [s] since the first tick, the
// releasing phase's force target [N]).
constexpr int kPhase = 0, kFiltered = 1, kRamp = 2, kPrimed = 3, kRampRate = 4, kElapsed = 5,
              kReleaseTarget = 6;

bool IsAdmittance(double phase) {
  const int p = static_cast<int>(phase);
  return p == static_cast<int>(GripperPhase::kHolding) ||
         p == static_cast<int>(GripperPhase::kReleasing);
}

}  // namespace

void GripperAdmittanceOptions::Check(const std::string& who) const {
  const auto positive = [&](double x, const char* what) {
    if (!(x > 0.0) || !std::isfinite(x))
      throw SotError(who + ": " + what + " must be > 0, got " + std::to_string(x));
  };
  positive(force_target, "force_target");
  positive(force_threshold, "force_threshold");
  positive(release_force, "release_force");
  positive(admittance_gain, "admittance_gain");
  positive(lever_arm, "lever_arm");
  positive(cutoff_frequency, "cutoff_frequency");
  positive(speed, "speed");
  positive(release_rate, "release_rate");
  positive(acceleration, "acceleration");
  positive(task_gain, "task_gain");
  positive(dt, "dt");
  if (!std::isfinite(torque_per_effort) || torque_per_effort == 0.0) {
    throw SotError(who + ": torque_per_effort must be finite and non-zero");
  }
  if (!(release_after >= 0.0) || !std::isfinite(release_after)) {
    throw SotError(who + ": release_after must be >= 0 s, got " + std::to_string(release_after));
  }
  if (closing_direction != 1.0 && closing_direction != -1.0) {
    throw SotError(who + ": closing_direction must be +1 or -1, got " +
                   std::to_string(closing_direction));
  }
  // The switch must happen before the target is reached, and the release must end below it
  // (§3.2.4.3: "a selected threshold, slightly below the desired gripping force").
  if (force_threshold >= force_target) {
    throw SotError(who + ": force_threshold (" + std::to_string(force_threshold) +
                   " N) must be below force_target (" + std::to_string(force_target) + " N)");
  }
  if (release_force >= force_threshold) {
    throw SotError(who + ": release_force (" + std::to_string(release_force) +
                   " N) must be below force_threshold (" + std::to_string(force_threshold) + " N)");
  }
}

FeatureGripperAdmittance::FeatureGripperAdmittance(std::string name, ModelPtr model,
                                                   const std::string& joint, double position_target,
                                                   bool release, GripperAdmittanceOptions options)
    : Feature(std::move(name), std::move(model), 1, {}), options_(options) {
  options_.Check(who());
  if (!model_->existJointName(joint)) {
    throw SotError(who() + ": unknown joint '" + joint + "' in model '" + model_->name + "'");
  }
  const pinocchio::JointIndex j = model_->getJointId(joint);
  if (model_->nvs[j] != 1 || model_->nqs[j] != 1) {
    throw SotError(who() + ": joint '" + joint +
                   "' is not a 1-DoF bounded joint (a gripper joint)");
  }
  if (!std::isfinite(position_target)) throw SotError(who() + ": position_target is not finite");
  iq_ = model_->idx_qs[j];
  iv_ = model_->idx_vs[j];
  alpha_ = 1.0 - std::exp(-2.0 * M_PI * options_.cutoff_frequency * options_.dt);
  SetUnitJacobian({iv_});

  effort_ = &DeclareInput<Eigen::VectorXd>("effort", Eigen::VectorXd::Zero(model_->nv));
  q_measured_ =
      &DeclareParameter<Eigen::VectorXd>("q_measured", pinocchio::neutral(*model_), false);
  applied_velocity_ = &DeclareParameter<Eigen::VectorXd>("applied_velocity",
                                                         Eigen::VectorXd::Zero(model_->nv), false);
  position_target_ = &DeclareParameter<double>("position_target", position_target);
  release_ = &DeclareParameter<bool>("release", release);
  // A releasing task that waits first starts by holding what the previous controller held.
  holds_what_was_held_ = release && options_.release_after > 0.0;
  const GripperPhase first = !release                       ? GripperPhase::kClosing
                             : options_.release_after > 0.0 ? GripperPhase::kHolding
                                                            : GripperPhase::kReleasing;
  Eigen::VectorXd initial(7);
  initial << static_cast<double>(first), 0.0, 0.0, 0.0, 0.0, 0.0, options_.force_target;
  force_ = &DeclareOutput<double>("force", 0.0, &FeatureGripperAdmittance::CalcForce, {effort_});
  machine_ = &DeclareState<Eigen::VectorXd>(
      "machine", initial, &FeatureGripperAdmittance::UpdateMachine,
      {kinematics_, force_, position_target_, release_, applied_velocity_});
  force_filtered_ = &DeclareOutput<double>(
      "force_filtered", 0.0, &FeatureGripperAdmittance::CalcForceFiltered, {machine_, force_});
  phase_ = &DeclareOutput<double>("phase", initial[kPhase], &FeatureGripperAdmittance::CalcPhase,
                                  {machine_});
  measured_position_ = &DeclareOutput<double>(
      "measured_position", 0.0, &FeatureGripperAdmittance::CalcMeasuredPosition, {q_measured_});
  DeclareTermsOutput({effort_, position_target_, machine_, force_, force_filtered_, phase_,
                      measured_position_, applied_velocity_});
}

double FeatureGripperAdmittance::RampRateNow(const graph::Tick& t, const Eigen::VectorXd& x) const {
  if (x[kPrimed] != 0.0) return x[kRampRate];
  return std::clamp(applied_velocity_->Eval(t)[iv_], -options_.speed, options_.speed);
}

double FeatureGripperAdmittance::RampRate(double r, double rate, double target) const {
  // The speed from which a deceleration `acceleration` stops on the target, |ṙ| <= speed, reached
  // from the current rate within ±acceleration·dt (no velocity step: the controller's start
  // check refuses a command that jumps).
  const double e = target - r, a = options_.acceleration, dt = options_.dt;
  double stop =
      std::abs(e) <= a * dt * dt ? e / dt : std::copysign(std::sqrt(2.0 * a * std::abs(e)), e);
  stop = std::clamp(stop, -options_.speed, options_.speed);
  return std::clamp(stop, rate - a * dt, rate + a * dt);
}

void FeatureGripperAdmittance::CalcForce(const graph::Tick& t, double* out) const {
  // eq. 3.11–3.13: f = s · k_τ k_gear · I / d.
  *out = options_.closing_direction * options_.torque_per_effort * effort_->Eval(t)[iv_] /
         options_.lever_arm;
}

double FeatureGripperAdmittance::AdmittanceTarget(const Eigen::VectorXd& x, double y) const {
  if (static_cast<int>(x[kPhase]) == static_cast<int>(GripperPhase::kHolding)) {
    if (!holds_what_was_held_) return options_.force_target;
    return x[kPrimed] != 0.0 ? x[kReleaseTarget] : std::clamp(y, 0.0, options_.force_target);
  }
  // Releasing: from the force held (the first tick of a releasing controller: y itself, so the
  // command does not step), down at release_rate.
  return x[kPrimed] != 0.0 ? x[kReleaseTarget] : std::clamp(y, 0.0, options_.force_target);
}

double FeatureGripperAdmittance::FilteredNow(const graph::Tick& t, const Eigen::VectorXd& x) const {
  return x[kPrimed] != 0.0 ? x[kFiltered] : force_->Eval(t);
}

void FeatureGripperAdmittance::CalcForceFiltered(const graph::Tick& t, double* out) const {
  *out = FilteredNow(t, machine_->Eval(t));
}

void FeatureGripperAdmittance::CalcPhase(const graph::Tick& t, double* out) const {
  *out = machine_->Eval(t)[kPhase];
}

void FeatureGripperAdmittance::CalcMeasuredPosition(const graph::Tick& t, double* out) const {
  *out = q_measured_->Eval(t)[iq_];
}

void FeatureGripperAdmittance::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                                           FeatureTerms* full) const {
  const Eigen::VectorXd& x = machine_->Eval(t);
  const double q = kinematics.q()[iq_];
  // Pulled every tick with the terms, so that introspection (`marionette dg get/trace`, which
  // reads cached values) sees this tick's force, phase and measured position.
  force_filtered_->Eval(t);
  phase_->Eval(t);
  measured_position_->Eval(t);
  if (IsAdmittance(x[kPhase])) {
    // λ e = s K_a (y − f*)  →  the task's v = −λ e = s K_a (f* − y).
    const double y = force_filtered_->Eval(t);
    const double f_target = AdmittanceTarget(x, y);
    full->error[0] =
        options_.closing_direction * options_.admittance_gain * (y - f_target) / options_.task_gain;
    full->drift[0] = 0.0;
  } else {
    const double r =
        x[kPrimed] != 0.0 ? x[kRamp] : q;  // the ramp starts where the joint is, as it moves
    full->error[0] = q - r;
    full->drift[0] = -RampRate(r, RampRateNow(t, x), position_target_->Eval(t));
  }
}

void FeatureGripperAdmittance::UpdateMachine(const graph::Tick& t, const Eigen::VectorXd& x,
                                             Eigen::VectorXd* next) const {
  const double q = kinematics_->Eval(t).q()[iq_];
  const double f = force_->Eval(t);
  const double y = FilteredNow(t, x);
  const double y_next = y + alpha_ * (f - y);
  const double elapsed = x[kElapsed] + options_.dt;
  const bool release = release_->Eval(t) && elapsed > options_.release_after;
  const double target = position_target_->Eval(t);
  int phase = static_cast<int>(x[kPhase]);
  double r = x[kPrimed] != 0.0 ? x[kRamp] : q;
  double rate = RampRateNow(t, x);
  if (IsAdmittance(phase)) {
    // Where the command goes this tick (v = −λ e of ComputeFull), so a switch back to position
    // control starts its ramp on the joint and at its speed: no jump in the error or the command.
    rate = options_.closing_direction * options_.admittance_gain * (AdmittanceTarget(x, y) - y);
    r = q + options_.dt * rate;
  } else {
    rate = RampRate(r, rate, target);
    r += options_.dt * rate;
  }
  switch (static_cast<GripperPhase>(phase)) {
    case GripperPhase::kClosing:
      if (release) {
        phase = static_cast<int>(y_next < options_.release_force ? GripperPhase::kOpening
                                                                 : GripperPhase::kReleasing);
      } else if (y_next > options_.force_threshold) {
        phase = static_cast<int>(GripperPhase::kHolding);
      }
      break;
    case GripperPhase::kHolding:
      if (release) phase = static_cast<int>(GripperPhase::kReleasing);
      break;
    case GripperPhase::kReleasing:
      if (y_next < options_.release_force) phase = static_cast<int>(GripperPhase::kOpening);
      break;
    case GripperPhase::kOpening:
      if (!release) phase = static_cast<int>(GripperPhase::kClosing);
      break;
  }
  (*next)[kPhase] = phase;
  (*next)[kFiltered] = y_next;
  (*next)[kRamp] = r;
  (*next)[kPrimed] = 1.0;
  (*next)[kRampRate] = rate;
  (*next)[kElapsed] = elapsed;
  // The releasing target starts at the force held when the phase begins and ramps to 0 N: a step
  // to 0 N would step the command by K_a f* (0.1 rad/s), what a controller switch refuses.
  double release_target = options_.force_target;
  if (phase == static_cast<int>(GripperPhase::kHolding) && holds_what_was_held_) {
    release_target = AdmittanceTarget(x, y);  // the force of the first tick, kept
  } else if (phase == static_cast<int>(GripperPhase::kReleasing)) {
    release_target =
        x[kPhase] == static_cast<double>(GripperPhase::kReleasing)
            ? std::max(0.0, AdmittanceTarget(x, y) - options_.release_rate * options_.dt)
            : std::clamp(y, 0.0, options_.force_target);
  }
  (*next)[kReleaseTarget] = release_target;
}

}  // namespace marionette::sot
