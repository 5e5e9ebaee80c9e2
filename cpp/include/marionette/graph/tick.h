#pragma once
/// The controller clock: a tick index (1 kHz in the controller) and its time.

#include <cstdint>

namespace marionette::graph {

/// One evaluation instant of the graph. Outputs cache their value per tick index (SoT's time
/// stamp): an output pulled twice in the same tick is computed once.
struct Tick {
  int64_t index = 0;  ///< strictly increasing between evaluations
  double time = 0.0;  ///< [s] controller time of this tick
  double dt = 1e-3;   ///< [s] period to the next tick

  Tick& operator++() {
    ++index;
    time += dt;
    return *this;
  }
};

}  // namespace marionette::graph
