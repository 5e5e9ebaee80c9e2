#pragma once
/// The supervisor's heartbeat, sent from a thread that never waits for anyone else's lock.
///
/// A controller holds the robot when its supervisor falls silent (--supervisor-timeout, 100 ms
/// by default). A heartbeat sent by a Python thread is silent whenever another thread keeps the
/// interpreter's lock for longer than that (a long call into a C extension, a plot), and the
/// controller then holds a robot whose supervisor is alive. This one beats from its own thread
/// and its own LCM instance: COMMAND "heartbeat" every `period_s`, signed when given a key.
///
/// It beats only while its owner shows it is alive: Feed() (the owner's loop calls it, in Python
/// from a thread of its own) must have been called within the last `hang_s`. So a supervisor
/// process that dies is silent at once (its threads die with it), one that hangs is silent
/// hang_s later, and one merely kept from running for less than hang_s stays heard.
///
/// Each beat names its process (pid and pid namespace): a controller on the same machine watches
/// that process and holds the robot the moment it exits, instead of after its timeout.

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

namespace lcm {
class LCM;
}

namespace marionette::wire {

class Signer;

struct HeartbeatOptions {
  double period_s = 0.02;  ///< between two beats
  double hang_s = 2.0;     ///< beats stop when Feed() was not called for this long
};

class Heartbeat {
 public:
  /// Starts beating on `url` as `source` (the command's source field); `key` empty: unsigned.
  /// Throws std::invalid_argument on a bad option, std::runtime_error if LCM cannot start.
  Heartbeat(const std::string& url, std::string source, const std::string& key,
            HeartbeatOptions options = {});
  ~Heartbeat();  ///< Stop()
  Heartbeat(const Heartbeat&) = delete;
  Heartbeat& operator=(const Heartbeat&) = delete;

  /// The owner is alive (lock-free; from one thread of the owner).
  void Feed();
  /// Stops beating and joins the thread (idempotent).
  void Stop();

  int64_t beats() const { return beats_.load(std::memory_order_relaxed); }
  /// Beats not sent because the owner had not fed it within hang_s.
  int64_t withheld() const { return withheld_.load(std::memory_order_relaxed); }
  /// The longest time between two Feed() calls so far [s]: how long the owner was kept from
  /// running (what a heartbeat sent by the owner itself would have been silent for).
  double longest_feed_gap_s() const {
    return 1e-6 * static_cast<double>(longest_gap_us_.load(std::memory_order_relaxed));
  }
  /// The longest time between two beats sent so far [s] (period_s when the machine keeps up;
  /// more when the thread waited for a CPU or was withheld).
  double longest_beat_gap_s() const {
    return 1e-6 * static_cast<double>(longest_beat_gap_us_.load(std::memory_order_relaxed));
  }

 private:
  void Run();

  HeartbeatOptions options_;
  std::string source_;
  std::unique_ptr<lcm::LCM> lcm_;
  std::unique_ptr<Signer> signer_;
  std::atomic<int64_t> fed_us_{0};
  std::atomic<int64_t> beats_{0};
  std::atomic<int64_t> withheld_{0};
  std::atomic<int64_t> longest_gap_us_{0};
  std::atomic<int64_t> longest_beat_gap_us_{0};
  std::mutex mutex_;
  std::condition_variable wake_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace marionette::wire
