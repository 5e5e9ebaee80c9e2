#include "marionette/graph/profiling.h"

#include <algorithm>
#include <cmath>

namespace marionette::graph {

thread_local ProfileScope* ProfileScope::current_ = nullptr;

void DurationHistogram::Add(double ns) {
  const double octaves = ns > kFirstBinNs ? std::log2(ns / kFirstBinNs) : 0.0;
  const int bin = std::min(kNumBins - 1, static_cast<int>(octaves * kBinsPerOctave));
  ++counts[bin];
  ++num_samples;
  max_ns = std::max(max_ns, ns);
}

void DurationHistogram::Clear() {
  counts.fill(0);
  num_samples = 0;
  max_ns = 0.0;
}

double DurationHistogram::Quantile(double p) const {
  if (num_samples == 0) return 0.0;
  const int64_t rank = std::max<int64_t>(1, static_cast<int64_t>(std::ceil(p * num_samples)));
  int64_t seen = 0;
  for (int b = 0; b < kNumBins; ++b) {
    seen += counts[b];
    if (seen >= rank) {
      const double upper = kFirstBinNs * std::exp2(static_cast<double>(b + 1) / kBinsPerOctave);
      return std::min(upper, max_ns);
    }
  }
  return max_ns;
}

}  // namespace marionette::graph
