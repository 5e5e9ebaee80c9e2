#pragma once
/// DriverDevice: a robot behind a driver process as the graph's device (graph/device.h;
/// protocol: docs/driver.md, driver_protocol.h). The driver's clock sets the pace: the loop
/// offers each DRIVER_STATE it receives (Offer), runs one tick per state taken — Read(t) puts the
/// state in the sources, Write(t) answers it on DRIVER_COMMAND with the state's sequence — and
/// holds when states stop or a state is refused.
///
/// Refused, with the reason (Offer): a message the schema's bounds refuse (wrong type, lying
/// sizes, NaN or absurd values), another protocol version, other joints or wrench bodies than the
/// robot's, a missing base on a floating robot, a sequence or a clock that does not advance
/// (out of order, duplicated), a clock that jumps by more than `max_clock_step_us`.
/// Counted, not refused: skipped sequence numbers (states the driver did not send or LCM lost).
///
/// Real-time: no allocation once the first state and command have sized their messages, but on
/// the path of a refused state (its reason is a string).

#include <lcm/lcm-cpp.hpp>
#include <string>

#include "marionette/controller/driver_protocol.h"
#include "marionette/graph/device.h"

namespace marionette::controller {

class DriverDevice final : public graph::Device {
 public:
  /// `first`: the robot's first state (its configuration is the device's initial one; it is also
  /// the state of tick 0). `lcm`: where commands go (nullptr: nowhere, for replays); it must
  /// outlive the device.
  DriverDevice(std::string name, DriverLayout layout, const MeasuredState& first, lcm::LCM* lcm,
               int64_t max_clock_step_us);
  const char* type_name() const override { return "DriverDevice"; }

  /// Why a state was refused: a category (counted per category) and one line of detail.
  struct Refusal {
    std::string category, detail;
  };
  /// A DRIVER_STATE message's bytes: validated (bounds), decoded, checked against the robot and
  /// the last state taken. True when it is the state of the next tick (has_state()).
  bool Offer(const void* data, size_t size, Refusal* refusal);
  /// A state waits for the next tick.
  bool has_state() const { return has_state_; }
  int64_t missed_states() const { return missed_states_; }
  const MeasuredState& last_state() const { return state_; }
  const DriverLayout& layout() const { return reader_.layout(); }

  /// Track (0) or hold (1): the mode the next commands carry.
  void set_command_mode(int8_t mode) { command_.mode = mode; }

  /// The waiting state into the sources.
  void Read(const graph::Tick& t) override;
  /// The command inputs to DRIVER_COMMAND, answering the state read this tick.
  void Write(const graph::Tick& t) override;
  /// The last command written (tests, replay).
  const JointCommand& command() const { return command_; }

 private:
  StateReader reader_;
  lcm::LCM* lcm_;
  int64_t max_clock_step_us_;
  lcmt_driver_state message_;  // decoded into (sized by the first state)
  MeasuredState state_;        // the state of this tick (or the waiting one)
  bool has_state_ = false;
  bool first_ = true;  // no previous state to compare the clock with
  int64_t missed_states_ = 0;
  JointCommand command_;
  lcmt_driver_command command_message_;
  std::vector<uint8_t> buffer_;  // the encoded command
};

/// The bytes of the first DRIVER_STATE on `lcm` that fits `layout`, waited for up to `timeout_s`
/// (0: forever); the first refusal of each kind is logged. Throws std::runtime_error when none
/// came.
std::string WaitFirstState(lcm::LCM& lcm, const DriverLayout& layout, double timeout_s);
/// The state in a DRIVER_STATE message's bytes; throws std::runtime_error saying why it does not
/// fit `layout`.
MeasuredState ReadState(const std::string& bytes, const DriverLayout& layout);

}  // namespace marionette::controller
