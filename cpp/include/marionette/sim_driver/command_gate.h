#pragma once
/// CommandGate: what a joint-level driver's servos track each control cycle, given the commands
/// that came (docs/driver.md). Pure logic on the robot's clock, no I/O, no allocation after
/// construction: marionette-sim runs it between publishing state k and stepping the physics.
///
/// Cycle k at robot time now (utime of state k):
///   - the command answering state k came: its targets (tracking);
///   - else the newest command taken, if now - its utime < timeout: its targets, and the cycle
///     is counted late (it ran on an older command);
///   - else hold: the joint positions measured when the hold began, zero velocity. The hold's
///     reaction is the robot time from the receipt of the last command to the hold (about the
///     timeout). Before the first command the driver holds the start posture (not counted as a
///     hold).
/// A command in mode 1 holds as well ("hold requested"). The first valid command in mode 0
/// after a hold resumes tracking.
///
/// Offer refuses a command that does not answer a state of this driver: a sequence not after the
/// newest one taken (duplicated, out of order), after the current cycle (from the future), or a
/// utime that is not its state's.

#include <Eigen/Core>
#include <cstdint>
#include <string>

#include "marionette/controller/driver_protocol.h"

namespace marionette::sim_driver {

enum class HoldReason : int {
  kNone = 0,
  kNoCommandYet,  ///< holding the start posture: no command taken yet
  kTimeout,       ///< the watchdog: no command younger than the timeout
  kRequested,     ///< the command in force has mode 1
};

class CommandGate {
 public:
  /// `period_us`: the control period (state k has utime k * period_us); `timeout_us`: the
  /// watchdog (a command older than this is not applied any more).
  CommandGate(int nq, int nv, int64_t period_us, int64_t timeout_us);

  /// A command received during cycle `cycle` (already read against the robot's joints). False
  /// with `why` (one line) when refused; then nothing changes.
  bool Offer(const controller::JointCommand& command, int64_t cycle, std::string* why);
  /// Whether the command answering `cycle` was taken (the cycle need not wait any more).
  bool HasCommandFor(int64_t cycle) const { return has_newest_ && newest_.sequence == cycle; }

  /// Decides the targets of cycle `cycle`; `q_measured` (nq): the configuration measured in it.
  void Decide(int64_t cycle, const Eigen::VectorXd& q_measured);

  // The decision of the last cycle.
  const Eigen::VectorXd& q() const { return q_; }  ///< servo position targets (nq)
  const Eigen::VectorXd& v() const { return v_; }  ///< servo velocity targets (nv)
  bool holding() const { return reason_ != HoldReason::kNone; }
  HoldReason reason() const { return reason_; }
  bool late() const { return late_; }  ///< ran on an older command than its own
  /// Robot time since the newest command's state (the age of what is applied or was) [us].
  int64_t command_age_us() const { return command_age_us_; }
  int64_t applied_sequence() const { return applied_sequence_; }  ///< -1: none (holding)

  // Counts since construction.
  int64_t commands_taken() const { return taken_; }      ///< commands Offer took
  int64_t commands_late() const { return late_count_; }  ///< cycles that ran late
  int64_t holds() const { return holds_; }               ///< holds engaged (watchdog or mode 1)
  double last_hold_reaction_ms() const { return last_hold_reaction_ms_; }  ///< watchdog holds

 private:
  int64_t period_us_, timeout_us_;
  controller::JointCommand newest_;  // the newest command taken
  bool has_newest_ = false;
  int64_t newest_received_us_ = 0;  // robot time of the cycle in which it came
  Eigen::VectorXd q_, v_;
  Eigen::VectorXd hold_q_;
  HoldReason reason_ = HoldReason::kNoCommandYet;
  bool started_ = false;  // Decide ran once (the start hold is in place)
  bool late_ = false;
  int64_t command_age_us_ = 0;
  int64_t applied_sequence_ = -1;
  int64_t taken_ = 0, late_count_ = 0, holds_ = 0;
  double last_hold_reaction_ms_ = 0.0;
};

}  // namespace marionette::sim_driver
