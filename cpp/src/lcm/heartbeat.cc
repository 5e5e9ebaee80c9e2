#include "marionette/lcm/heartbeat.h"

#include <unistd.h>
#include <chrono>
#include <cmath>

#include <lcm/lcm-cpp.hpp>
#include <stdexcept>
#include <utility>
#include <vector>

#include "marionette/lcm/channels.h"
#include "marionette/lcm/signing.h"
#include "marionette/lcmt_command.hpp"
#include "marionette/runtime/process_watch.h"

namespace marionette::wire {
namespace {

int64_t WallUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// max <- value if larger (one writer per maximum: Feed's thread, or Run's).
void RaiseTo(std::atomic<int64_t>& max, int64_t value) {
  if (value > max.load(std::memory_order_relaxed)) max.store(value, std::memory_order_relaxed);
}

}  // namespace

Heartbeat::Heartbeat(const std::string& url, std::string source, const std::string& key,
                     HeartbeatOptions options)
    : options_(options), source_(std::move(source)) {
  if (!(options_.period_s > 0.0 && std::isfinite(options_.period_s))) {
    throw std::invalid_argument("heartbeat: period_s must be > 0 (got " +
                                std::to_string(options_.period_s) + ")");
  }
  if (!(options_.hang_s >= options_.period_s && std::isfinite(options_.hang_s))) {
    throw std::invalid_argument("heartbeat: hang_s must be >= period_s (got " +
                                std::to_string(options_.hang_s) + ")");
  }
  lcm_ = std::make_unique<lcm::LCM>(url);
  if (!lcm_->good()) throw std::runtime_error("heartbeat: cannot start LCM on '" + url + "'");
  if (!key.empty()) signer_ = std::make_unique<Signer>(key);
  Feed();
  thread_ = std::thread([this] { Run(); });
}

Heartbeat::~Heartbeat() { Stop(); }

void Heartbeat::Feed() {
  const int64_t now_us = WallUs();
  const int64_t last_us = fed_us_.exchange(now_us, std::memory_order_relaxed);
  if (last_us > 0) RaiseTo(longest_gap_us_, now_us - last_us);
}

void Heartbeat::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void Heartbeat::Run() {
  lcmt_command msg;
  msg.command = "heartbeat";
  msg.source = source_;
  // Who beats, so that a controller on this machine also sees the moment this process exits.
  msg.sender_pid = static_cast<int32_t>(getpid());
  msg.sender_pid_namespace = runtime::ThisProcessNamespace();
  std::vector<uint8_t> buffer;
  int64_t last_beat_us = 0;
  const auto period = std::chrono::duration<double>(options_.period_s);
  auto next = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
    if (wake_.wait_until(lock, next, [this] { return stop_; })) return;
    const int64_t now_us = WallUs();
    if (1e-6 * static_cast<double>(now_us - fed_us_.load(std::memory_order_relaxed)) >
        options_.hang_s) {
      withheld_.fetch_add(1, std::memory_order_relaxed);
      continue;
    }
    msg.utime = now_us;
    buffer.resize(static_cast<size_t>(msg.getEncodedSize()));
    msg.encode(buffer.data(), 0, static_cast<int>(buffer.size()));
    if (signer_) {
      const std::string signed_message =
          signer_->Sign(channels::kCommand, buffer.data(), buffer.size(), now_us);
      lcm_->publish(channels::kCommand, signed_message.data(),
                    static_cast<unsigned int>(signed_message.size()));
    } else {
      lcm_->publish(channels::kCommand, buffer.data(), static_cast<unsigned int>(buffer.size()));
    }
    beats_.fetch_add(1, std::memory_order_relaxed);
    if (last_beat_us > 0) RaiseTo(longest_beat_gap_us_, now_us - last_beat_us);
    last_beat_us = now_us;
  }
}

}  // namespace marionette::wire
