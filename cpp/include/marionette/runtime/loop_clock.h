#pragma once
/// LoopClock: paces a periodic loop on absolute deadlines (deadline_k = start + k·period, so
/// compute-time jitter never accumulates into drift) and measures every tick.
///
/// `speed` scales wall time: 1 = real time, 2 = twice as fast, 0 = unpaced (as fast as possible,
/// deadlines ignored, nothing counted as missed). A tick that starts more than one period after
/// its deadline is a deadline miss; when the loop falls more than `max_backlog` periods behind,
/// the schedule is re-anchored instead of bursting to catch up.

#include <cstdint>
#include <ctime>
#include <string>

namespace marionette::runtime {

/// Measurements of one tick, in microseconds of wall time.
struct TickTiming {
  double period_us = 0.0;    // start of this tick minus start of the previous one
  double lateness_us = 0.0;  // start minus deadline (>= 0 in practice)
  double compute_us = 0.0;   // filled by the caller after the tick's work
};

class LoopClock {
 public:
  LoopClock(double period_s, double speed, int max_backlog = 50);

  /// Sleeps until the next deadline (absolute), then returns the measured start of the tick.
  TickTiming WaitNextTick();
  /// Microseconds since the start of the current tick (for compute time).
  double ElapsedInTickUs() const;

  int64_t ticks() const { return ticks_; }
  int64_t deadline_misses() const { return deadline_misses_; }
  int64_t reanchors() const { return reanchors_; }
  /// Wall seconds since the first tick.
  double WallSeconds() const;
  double period_s() const { return period_s_; }
  double speed() const { return speed_; }

 private:
  double period_s_;
  double speed_;
  int max_backlog_;
  int64_t wall_period_ns_;
  timespec start_{};
  timespec deadline_{};
  timespec tick_start_{};
  int64_t ticks_ = 0;
  int64_t deadline_misses_ = 0;
  int64_t reanchors_ = 0;
};

/// Outcome of asking the OS for real-time scheduling.
struct RealtimeStatus {
  bool fifo = false;    // SCHED_FIFO granted
  bool locked = false;  // mlockall granted
  std::string message;  // one line for the log, saying what was and was not granted and why
};

/// Tries SCHED_FIFO at `priority` for the calling thread and mlockall(MCL_CURRENT | MCL_FUTURE).
RealtimeStatus RequestRealtime(int priority);
/// Tries SCHED_FIFO at `priority` for the calling thread only (threads serving a real-time loop
/// below its priority); the message says whether it was granted and why not.
RealtimeStatus RequestThreadPriority(int priority);

}  // namespace marionette::runtime
