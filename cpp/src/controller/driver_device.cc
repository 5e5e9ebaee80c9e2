// A robot behind a driver process as the graph's device (driver_device.h).
#include "marionette/controller/driver_device.h"

#include <chrono>
#include <set>

#include "marionette/lcm/channels.h"
#include "marionette/lcm/validate.h"
#include "marionette/runtime/log_line.h"

namespace marionette::controller {

DriverDevice::DriverDevice(std::string name, DriverLayout layout, const MeasuredState& first,
                           lcm::LCM* lcm, int64_t max_clock_step_us)
    : Device(std::move(name), first.q, layout.nv, layout.wrench_bodies),
      reader_(std::move(layout)),
      lcm_(lcm),
      max_clock_step_us_(max_clock_step_us),
      state_(first),
      has_state_(true),
      first_(false) {
  command_.q = first.q;
  command_.v = Eigen::VectorXd::Zero(first.v.size());
  WriteCommand(reader_.layout(), command_, &command_message_);  // sized once
  buffer_.resize(command_message_.getEncodedSize());
}

bool DriverDevice::Offer(const void* data, size_t size, Refusal* refusal) {
  const wire::Verdict verdict = wire::Validate<lcmt_driver_state>(data, size);
  if (!verdict.ok()) {
    *refusal = {wire::ToString(verdict.refusal), verdict.detail};
    return false;
  }
  if (message_.decode(data, 0, static_cast<int>(size)) != static_cast<int>(size)) {
    *refusal = {"undecodable", "not a valid lcmt_driver_state"};
    return false;
  }
  // Against the state taken last (the one waiting, or the last tick's).
  const int64_t last_sequence = state_.sequence, last_utime = state_.utime;
  if (!first_ && message_.sequence <= last_sequence) {
    *refusal = {message_.sequence == last_sequence ? "duplicated" : "out of order",
                "sequence " + std::to_string(message_.sequence) + " after " +
                    std::to_string(last_sequence)};
    return false;
  }
  if (!first_ && message_.utime <= last_utime) {
    *refusal = {"clock went back", "utime " + std::to_string(message_.utime) + " us after " +
                                       std::to_string(last_utime) + " us"};
    return false;
  }
  std::string why;
  if (!reader_.Read(message_, &state_, &why)) {
    *refusal = {"does not fit the robot", why};
    return false;
  }
  // From here state_ holds the new state, the reference of the next checks.
  const int64_t step = state_.utime - last_utime;
  if (!first_ && step > max_clock_step_us_) {
    has_state_ = false;  // continue from it, but do not act on it
    *refusal = {"clock jump", "the robot's clock jumped " + std::to_string(step / 1000) +
                                  " ms (at most " + std::to_string(max_clock_step_us_ / 1000) +
                                  " ms between two states)"};
    return false;
  }
  if (!first_) missed_states_ += state_.sequence - last_sequence - 1;
  first_ = false;
  has_state_ = true;
  return true;
}

void DriverDevice::Read(const graph::Tick&) {
  q_->mutable_value() = state_.q;
  v_->mutable_value() = state_.v;
  effort_->mutable_value() = state_.effort;
  for (size_t i = 0; i < wrenches_.size(); ++i)
    wrenches_[i]->mutable_value() = Eigen::Map<const Eigen::VectorXd>(&state_.wrenches[6 * i], 6);
  has_state_ = false;
}

void DriverDevice::Write(const graph::Tick& t) {
  command_.utime = state_.utime;
  command_.sequence = state_.sequence;
  command_.q = q_command_->Eval(t);
  command_.v = v_command_->Eval(t);
  if (lcm_ == nullptr) return;
  WriteCommand(reader_.layout(), command_, &command_message_);
  const int size = command_message_.encode(buffer_.data(), 0, static_cast<int>(buffer_.size()));
  if (size > 0) lcm_->publish(channels::kDriverCommand, buffer_.data(), size);
}

MeasuredState WaitFirstState(lcm::LCM& lcm, const DriverLayout& layout, double timeout_s) {
  struct Waiter {
    StateReader reader;
    MeasuredState state;
    bool taken = false;
    std::set<std::string> logged;
    void Handle(const lcm::ReceiveBuffer* rbuf, const std::string&) {
      if (taken) return;
      const wire::Verdict verdict = wire::Validate<lcmt_driver_state>(rbuf->data, rbuf->data_size);
      std::string why;
      lcmt_driver_state msg;
      if (!verdict.ok()) {
        why = std::string(wire::ToString(verdict.refusal)) + ": " + verdict.detail;
      } else if (msg.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) !=
                 static_cast<int>(rbuf->data_size)) {
        why = "undecodable";
      } else if (reader.Read(msg, &state, &why)) {
        taken = true;
        return;
      }
      if (logged.insert(why.substr(0, 40)).second)
        runtime::LogLine("[controller] DRIVER_STATE refused: ", why);
    }
  } waiter{StateReader(layout), {}, false, {}};
  lcm::Subscription* sub = lcm.subscribe(channels::kDriverState, &Waiter::Handle, &waiter);
  const auto start = std::chrono::steady_clock::now();
  while (!waiter.taken) {
    const double waited =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (timeout_s > 0.0 && waited >= timeout_s) break;
    lcm.handleTimeout(100);
  }
  lcm.unsubscribe(sub);
  if (!waiter.taken) {
    throw std::runtime_error("no DRIVER_STATE from " + layout.robot_name + "'s driver in " +
                             std::to_string(timeout_s) + " s (is the driver or marionette-sim " +
                             "running on this LCM URL? docs/driver.md)");
  }
  return waiter.state;
}

}  // namespace marionette::controller
