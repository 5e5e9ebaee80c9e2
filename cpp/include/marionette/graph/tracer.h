#pragma once
/// Tracer: records chosen signals every tick into a preallocated ring buffer, dumped after the
/// run (dynamic-graph's Tracer without its file I/O in the loop).
/// @entity  inputs: none (traced signals are read directly)   outputs: none

#include <string>
#include <vector>

#include "marionette/graph/entity.h"

namespace marionette::graph {

class Tracer final : public Entity {
 public:
  /// Records `signals` at every tick, keeping the last `capacity` ticks (>= 1). Each signal's
  /// value is flattened column-major into shape().size() columns named "entity.signal[i]".
  Tracer(std::string name, int capacity, std::vector<const SignalBase*> signals);
  const char* type_name() const override { return "Tracer"; }

  int capacity() const { return capacity_; }
  int size() const { return size_; }              ///< recorded rows, <= capacity
  int num_columns() const { return row_width_; }  ///< tick, time, then the traced values
  std::vector<std::string> column_names() const;
  /// Row i (0 = oldest kept) as tick, time, values...
  std::vector<double> Row(int i) const;
  /// Writes all rows, oldest first, as CSV with a header line.
  void WriteCsv(const std::string& path) const;
  void Clear() {
    size_ = 0;
    head_ = 0;
  }

 private:
  void Record(const Tick& t) const;

  int capacity_;
  int row_width_ = 2;
  std::vector<const SignalBase*> traced_;
  std::vector<int> offsets_;
  mutable std::vector<double> buffer_;  // capacity_ x row_width_, row-major ring
  mutable int head_ = 0;                // next row to write
  mutable int size_ = 0;
};

}  // namespace marionette::graph
