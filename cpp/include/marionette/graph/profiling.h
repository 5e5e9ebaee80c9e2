#pragma once
/// Per-entity compute time: when a graph's profiling is on, every Calc,
/// state update, update hook and poll hook is timed and charged to its entity as *self* time
/// (the time of the outputs it pulls from other entities is charged to them). At the end of each
/// tick the graph folds every entity's tick total into a histogram and checks its budget.
///
/// Off (the default), the only cost is one null-pointer test per computation.

#include <array>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

namespace marionette::graph {

/// Log-spaced histogram of durations: 4 bins per octave from 16 ns to ~17 s (resolution 19 %).
struct DurationHistogram {
  static constexpr int kBinsPerOctave = 4;
  static constexpr int kNumBins = 30 * kBinsPerOctave;
  static constexpr double kFirstBinNs = 16.0;
  std::array<int64_t, kNumBins> counts{};
  int64_t num_samples = 0;
  double max_ns = 0.0;

  void Add(double ns);
  void Clear();
  /// Upper edge of the bin holding the p-quantile (0 < p <= 1) [ns]; 0 when empty.
  double Quantile(double p) const;
};

/// What the graph measures of one entity.
struct EntityTiming {
  double tick_ns = 0.0;    ///< self time accumulated in the current tick
  double budget_ns = 0.0;  ///< 0 = no budget
  int64_t overruns = 0;    ///< ticks over budget since profiling started
  int64_t consecutive_overruns = 0;
  bool last_tick_over = false;  ///< the last evaluated tick exceeded the budget
  DurationHistogram window;     ///< ticks since the last ResetWindow
};

/// RAII timer charging self time to an EntityTiming (nested scopes subtract their time from
/// their parent's). Thread-local nesting: one graph evaluates on one thread.
class ProfileScope {
 public:
  explicit ProfileScope(EntityTiming* timing) : timing_(timing) {
    if (timing_ != nullptr) {
      parent_ = current_;
      current_ = this;
      start_ = Now();
    }
  }
  ~ProfileScope() {
    if (timing_ == nullptr) return;
    const double elapsed = Now() - start_;
    timing_->tick_ns += elapsed - children_ns_;
    current_ = parent_;
    if (parent_ != nullptr) parent_->children_ns_ += elapsed;
  }
  ProfileScope(const ProfileScope&) = delete;
  ProfileScope& operator=(const ProfileScope&) = delete;

  static double Now() {
    return static_cast<double>(std::chrono::duration_cast<std::chrono::nanoseconds>(
                                   std::chrono::steady_clock::now().time_since_epoch())
                                   .count());
  }

 private:
  EntityTiming* timing_;
  ProfileScope* parent_ = nullptr;
  double start_ = 0.0;
  double children_ns_ = 0.0;
  static thread_local ProfileScope* current_;
};

/// One entity's figures over a window, for status messages and the CLI.
struct EntityTimingStats {
  std::string entity;
  int64_t ticks = 0;
  double p50_us = 0.0, p99_us = 0.0, max_us = 0.0;
  double budget_us = 0.0;  ///< 0 = none
  int64_t overruns = 0;
};

}  // namespace marionette::graph
