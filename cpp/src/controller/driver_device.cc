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
      state_(first) {
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

namespace {

// Why `data` is not a state of `layout` ("" when it is one, then in `state`).
std::string CheckState(const void* data, size_t size, const DriverLayout& layout,
                       StateReader* reader, MeasuredState* state) {
  const wire::Verdict verdict = wire::Validate<lcmt_driver_state>(data, size);
  if (!verdict.ok()) return std::string(wire::ToString(verdict.refusal)) + ": " + verdict.detail;
  lcmt_driver_state msg;
  if (msg.decode(data, 0, static_cast<int>(size)) != static_cast<int>(size)) return "undecodable";
  std::string why;
  return reader->Read(msg, state, &why) ? std::string() : why;
}

}  // namespace

std::string WaitFirstState(lcm::LCM& lcm, const DriverLayout& layout, double timeout_s) {
  struct Waiter {
    const DriverLayout& layout;
    StateReader reader;
    std::string bytes;
    std::set<std::string> logged;
    void Handle(const lcm::ReceiveBuffer* rbuf, const std::string&) {
      if (!bytes.empty()) return;
      MeasuredState state;
      const std::string why = CheckState(rbuf->data, rbuf->data_size, layout, &reader, &state);
      if (why.empty()) {
        bytes.assign(static_cast<const char*>(rbuf->data), rbuf->data_size);
      } else if (logged.insert(why.substr(0, 40)).second) {
        runtime::LogLine("[controller] DRIVER_STATE refused: ", why);
      }
    }
  } waiter{layout, StateReader(layout), {}, {}};
  lcm::Subscription* sub = lcm.subscribe(channels::kDriverState, &Waiter::Handle, &waiter);
  const auto start = std::chrono::steady_clock::now();
  while (waiter.bytes.empty()) {
    const double waited =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    if (timeout_s > 0.0 && waited >= timeout_s) break;
    lcm.handleTimeout(100);
  }
  lcm.unsubscribe(sub);
  if (waiter.bytes.empty()) {
    throw std::runtime_error("no DRIVER_STATE from " + layout.robot_name + "'s driver in " +
                             std::to_string(timeout_s) + " s (is the driver or marionette-sim " +
                             "running on this LCM URL? docs/driver.md)");
  }
  return waiter.bytes;
}

MeasuredState ReadState(const std::string& bytes, const DriverLayout& layout) {
  StateReader reader(layout);
  MeasuredState state;
  const std::string why = CheckState(bytes.data(), bytes.size(), layout, &reader, &state);
  if (!why.empty()) throw std::runtime_error("DRIVER_STATE refused: " + why);
  return state;
}

}  // namespace marionette::controller
