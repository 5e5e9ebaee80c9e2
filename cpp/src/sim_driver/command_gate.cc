// What the servos track each cycle (command_gate.h).
#include "marionette/sim_driver/command_gate.h"

namespace marionette::sim_driver {

CommandGate::CommandGate(int nq, int nv, int64_t period_us, int64_t timeout_us)
    : period_us_(period_us),
      timeout_us_(timeout_us),
      q_(Eigen::VectorXd::Zero(nq)),
      v_(Eigen::VectorXd::Zero(nv)),
      hold_q_(Eigen::VectorXd::Zero(nq)) {
  newest_.q = Eigen::VectorXd::Zero(nq);
  newest_.v = Eigen::VectorXd::Zero(nv);
}

bool CommandGate::Offer(const controller::JointCommand& command, int64_t cycle, std::string* why) {
  if (has_newest_ && command.sequence <= newest_.sequence) {
    *why = (command.sequence == newest_.sequence ? "duplicated: sequence " : "out of order: ") +
           std::to_string(command.sequence) + " after " + std::to_string(newest_.sequence);
    return false;
  }
  if (command.sequence > cycle) {
    *why = "sequence " + std::to_string(command.sequence) + " answers no state yet (the last is " +
           std::to_string(cycle) + ")";
    return false;
  }
  if (command.utime != command.sequence * period_us_) {
    *why = "utime " + std::to_string(command.utime) + " us is not state " +
           std::to_string(command.sequence) + "'s (" +
           std::to_string(command.sequence * period_us_) + " us)";
    return false;
  }
  if (command.q.size() != newest_.q.size() || command.v.size() != newest_.v.size()) {
    *why = "command of " + std::to_string(command.q.size()) + " positions for " +
           std::to_string(newest_.q.size());
    return false;
  }
  newest_.utime = command.utime;
  newest_.sequence = command.sequence;
  newest_.mode = command.mode;
  newest_.q = command.q;  // same sizes: no allocation
  newest_.v = command.v;
  has_newest_ = true;
  ++taken_;
  newest_received_us_ = cycle * period_us_;
  return true;
}

void CommandGate::Decide(int64_t cycle, const Eigen::VectorXd& q_measured) {
  const int64_t now_us = cycle * period_us_;
  late_ = false;
  HoldReason reason = HoldReason::kNone;
  if (!has_newest_) {
    reason = HoldReason::kNoCommandYet;
  } else {
    command_age_us_ = now_us - newest_.utime;
    if (newest_.sequence != cycle && command_age_us_ >= timeout_us_) {
      reason = HoldReason::kTimeout;
    } else {
      late_ = newest_.sequence != cycle;
      if (newest_.mode == 1) reason = HoldReason::kRequested;
    }
  }
  if (late_) ++late_count_;
  if (reason == HoldReason::kNone) {
    applied_sequence_ = newest_.sequence;
    q_ = newest_.q;
    v_ = newest_.v;
    reason_ = reason;
    started_ = true;
    return;
  }
  applied_sequence_ = -1;
  if (!started_ || reason_ == HoldReason::kNone) {  // a hold begins: where the robot is now
    hold_q_ = q_measured;
    if (reason != HoldReason::kNoCommandYet) ++holds_;
    if (reason == HoldReason::kTimeout)
      last_hold_reaction_ms_ = 1e-3 * static_cast<double>(now_us - newest_received_us_);
  }
  reason_ = reason;
  started_ = true;
  q_ = hold_q_;
  v_.setZero();
}

}  // namespace marionette::sim_driver
