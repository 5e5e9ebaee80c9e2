#pragma once
/// Percentile statistics of a duration over a sliding window of samples (controller status:
/// tick period, compute time, lateness). Not for the loop thread: Summarise() sorts.

#include <cstddef>
#include <cstdint>
#include <vector>

namespace marionette::runtime {

struct TimingSummary {
  int64_t num_samples = 0;
  double p50 = 0.0;
  double p99 = 0.0;
  double max = 0.0;
  double mean = 0.0;
};

class TimingWindow {
 public:
  explicit TimingWindow(size_t capacity);
  void Add(double sample);
  size_t size() const { return size_; }
  /// Nearest-rank percentiles (p50 = value at rank ceil(0.5 n)) of the samples in the window.
  TimingSummary Summarise() const;
  void Clear() {
    size_ = 0;
    next_ = 0;
  }

 private:
  std::vector<double> samples_;
  size_t next_ = 0;
  size_t size_ = 0;
  mutable std::vector<double> sorted_;
};

}  // namespace marionette::runtime
