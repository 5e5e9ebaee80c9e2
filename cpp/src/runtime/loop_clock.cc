#include "marionette/runtime/loop_clock.h"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <cerrno>
#include <cmath>
#include <cstring>

namespace marionette::runtime {
namespace {

constexpr int64_t kNsPerS = 1000000000;

int64_t ToNs(const timespec& t) { return t.tv_sec * kNsPerS + t.tv_nsec; }

timespec FromNs(int64_t ns) { return timespec{ns / kNsPerS, ns % kNsPerS}; }

timespec Now() {
  timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return t;
}

}  // namespace

LoopClock::LoopClock(double period_s, double speed, int max_backlog)
    : period_s_(period_s),
      speed_(speed),
      max_backlog_(max_backlog),
      wall_period_ns_(speed > 0.0 ? static_cast<int64_t>(std::llround(period_s * kNsPerS / speed))
                                  : 0) {}

TickTiming LoopClock::WaitNextTick() {
  TickTiming timing;
  const timespec previous_start = tick_start_;
  if (ticks_ == 0) {
    start_ = Now();
    deadline_ = start_;
    tick_start_ = start_;
  } else if (wall_period_ns_ == 0) {
    tick_start_ = Now();  // unpaced: no deadline
  } else {
    deadline_ = FromNs(ToNs(deadline_) + wall_period_ns_);
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline_, nullptr) == EINTR) {
    }
    tick_start_ = Now();
    const int64_t late_ns = ToNs(tick_start_) - ToNs(deadline_);
    timing.lateness_us = late_ns * 1e-3;
    if (late_ns > wall_period_ns_) ++deadline_misses_;
    if (late_ns > max_backlog_ * wall_period_ns_) {
      deadline_ = tick_start_;  // too far behind: re-anchor rather than burst
      ++reanchors_;
    }
  }
  if (ticks_ > 0) timing.period_us = (ToNs(tick_start_) - ToNs(previous_start)) * 1e-3;
  ++ticks_;
  return timing;
}

double LoopClock::ElapsedInTickUs() const { return (ToNs(Now()) - ToNs(tick_start_)) * 1e-3; }

double LoopClock::WallSeconds() const {
  return ticks_ == 0 ? 0.0 : (ToNs(Now()) - ToNs(start_)) * 1e-9;
}

RealtimeStatus RequestRealtime(int priority) {
  RealtimeStatus status;
  sched_param param{};
  param.sched_priority = priority;
  const int fifo_error = sched_setscheduler(0, SCHED_FIFO, &param) == 0 ? 0 : errno;
  status.fifo = fifo_error == 0;
  const int lock_error = mlockall(MCL_CURRENT | MCL_FUTURE) == 0 ? 0 : errno;
  status.locked = lock_error == 0;
  status.message = std::string("real-time: SCHED_FIFO priority ") + std::to_string(priority) +
                   (status.fifo ? " granted"
                                : std::string(" REFUSED (") + std::strerror(fifo_error) +
                                      "; needs root or CAP_SYS_NICE / rtprio limit)") +
                   ", mlockall " +
                   (status.locked ? "granted"
                                  : std::string("REFUSED (") + std::strerror(lock_error) +
                                        "; needs CAP_IPC_LOCK or a memlock limit)");
  return status;
}

RealtimeStatus RequestThreadPriority(int priority) {
  RealtimeStatus status;
  sched_param param{};
  param.sched_priority = priority;
  const int error = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
  status.fifo = error == 0;
  status.message =
      std::string("SCHED_FIFO priority ") + std::to_string(priority) +
      (status.fifo ? " granted" : std::string(" REFUSED (") + std::strerror(error) + ")");
  return status;
}

}  // namespace marionette::runtime
