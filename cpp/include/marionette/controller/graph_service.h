#pragma once
/// GraphService: the running graph seen and poked from another process (DG_REQUEST), without
/// ever blocking or delaying the tick.
///
///   LCM thread                               loop thread (end of each tick)
///   ----------                               ------------------------------
///   ls / graph / timing: read the structure  —
///     (only while no controller swap is pending: the structure is then frozen)
///   get / trace: resolve names, post a Watch  ApplySets() (start): take the posted watch;
///     (atomic pointer swap)                    Sample() (end): flatten the watched signals
///                                              into a preallocated slot of a lock-free queue
///   drain samples: reply to gets, publish     —
///     traces at their rate
///   set: only inputs declared settable;       ApplySets(): copy the values into the input
///     queued with their values                 (same size: no allocation)
///
/// A controller swap removes entities: the loop drops the watch when it applies one
/// (Invalidate), and the LCM thread re-resolves the traced names against the new graph.

#include <array>
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "marionette/graph/graph.h"
#include "marionette/runtime/spsc_queue.h"

namespace marionette::controller {

/// The signals the loop copies at the end of each tick.
struct Watch {
  int64_t id = 0;  // unique: samples name the watch they come from
  std::vector<graph::SignalBase*> signals;
  std::vector<int> offsets;  // into a sample's values
  int total_size = 0;
};

struct WatchSample {
  int64_t tick = -1;
  int64_t utime = 0;
  int64_t watch_id = -1;  // which watch these values belong to
  std::vector<double> values;
};

struct SetRequest {
  graph::InputSignalBase* input = nullptr;
  int64_t hash = 0;  // of the request message (controller journal)
  int size = 0;
  std::array<double, 64> values{};
};

class GraphService {
 public:
  static constexpr int kMaxSetSize = 64;
  static constexpr int kMaxWatchedValues = 4096;

  GraphService();
  ~GraphService();

  // ---- loop thread (real-time: no allocation, no lock) --------------------------------------
  /// Takes the watch last posted, then applies the queued `set` requests (call at the start of
  /// every tick); writes the hashes of the requests applied into hashes[0 .. returned count), at
  /// most `max`.
  int ApplySets(int64_t* hashes, int max);
  /// Copies the watched signals (call at the end of a tick, after evaluation).
  void Sample(int64_t tick, int64_t utime);
  /// Drops the watch (call when a controller swap was applied: watched entities may be gone).
  void Invalidate();

  // ---- LCM thread ----------------------------------------------------------------------------
  /// Replaces the watch with `signals` (empty = none); returns the new watch's id. The previous
  /// watch is freed later, here, once the loop has let go of it.
  int64_t SetWatch(std::vector<graph::SignalBase*> signals);
  /// The watch with that id (nullptr once freed).
  const Watch* FindWatch(int64_t id) const;
  /// The oldest sample not yet consumed (nullptr when none); PopSample() releases it.
  const WatchSample* FrontSample() const;
  void PopSample();
  /// Queues a set; returns "" or why it is refused (not an input, not settable, wrong size).
  std::string QueueSet(graph::SignalBase& signal, const std::vector<double>& values, int64_t hash);
  /// Frees watches the loop no longer uses.
  void CollectGarbage();

 private:
  std::atomic<Watch*> posted_{nullptr};              // LCM -> loop
  std::atomic<bool> invalidated_{false};             // loop -> LCM: a swap dropped the watch
  Watch* active_ = nullptr;                          // loop-owned
  runtime::SpscQueue<Watch*> retired_{64};           // loop -> LCM
  std::map<int64_t, std::unique_ptr<Watch>> owned_;  // LCM-owned storage of every live watch
  int64_t next_id_ = 1;
  runtime::SpscQueue<WatchSample> samples_;
  runtime::SpscQueue<SetRequest> sets_;
};

/// "entity (Type)" lines with their signals: kind, type, shape, plug or value, settable flag.
std::string ListGraph(const graph::Graph& graph);

}  // namespace marionette::controller
