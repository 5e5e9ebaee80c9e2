#include "marionette/runtime/timing_stats.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace marionette::runtime {

TimingWindow::TimingWindow(size_t capacity) : samples_(capacity), sorted_(capacity) {}

void TimingWindow::Add(double sample) {
  samples_[next_] = sample;
  next_ = (next_ + 1) % samples_.size();
  size_ = std::min(size_ + 1, samples_.size());
}

TimingSummary TimingWindow::Summarise() const {
  TimingSummary s;
  s.num_samples = static_cast<int64_t>(size_);
  if (size_ == 0) return s;
  sorted_.assign(samples_.begin(), samples_.begin() + size_);
  std::sort(sorted_.begin(), sorted_.end());
  const auto rank = [&](double p) {
    const size_t k = static_cast<size_t>(std::ceil(p * size_));
    return sorted_[std::min(size_, std::max<size_t>(k, 1)) - 1];
  };
  s.p50 = rank(0.50);
  s.p99 = rank(0.99);
  s.max = sorted_.back();
  s.mean = std::accumulate(sorted_.begin(), sorted_.end(), 0.0) / size_;
  return s;
}

}  // namespace marionette::runtime
