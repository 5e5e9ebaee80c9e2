#pragma once
/// TripleBuffer<T>: hands the latest value from one writer thread to one reader thread without
/// locks, without blocking either side, and without allocation once the three slots hold
/// values of their final size. The reader always gets the newest complete value.
///
///   writer:  T& slot = tb.write_slot(); fill(slot); tb.Publish();
///   reader:  if (tb.Fetch()) use(tb.read_slot());

#include <atomic>
#include <cstdint>

namespace marionette::runtime {

template <typename T>
class TripleBuffer {
 public:
  /// All three slots start as copies of `model` (give vectors their final sizes here).
  explicit TripleBuffer(const T& model = T()) : slots_{model, model, model} {}
  TripleBuffer(const TripleBuffer&) = delete;
  TripleBuffer& operator=(const TripleBuffer&) = delete;

  /// The slot the writer may fill (never read by the reader until Publish()).
  T& write_slot() { return slots_[write_]; }

  /// Makes the written slot the newest value; the writer gets a free slot for next time.
  void Publish() {
    const uint8_t previous =
        middle_.exchange(static_cast<uint8_t>(write_ | kFresh), std::memory_order_acq_rel);
    write_ = previous & kIndexMask;
  }

  /// Takes the newest published value if there is one since the last Fetch; returns whether
  /// read_slot() changed.
  bool Fetch() {
    if ((middle_.load(std::memory_order_acquire) & kFresh) == 0) return false;
    const uint8_t previous = middle_.exchange(read_, std::memory_order_acq_rel);
    read_ = previous & kIndexMask;
    return true;
  }

  /// The value taken by the last successful Fetch (the model before any).
  const T& read_slot() const { return slots_[read_]; }
  T& mutable_read_slot() { return slots_[read_]; }

 private:
  static constexpr uint8_t kFresh = 0x4;
  static constexpr uint8_t kIndexMask = 0x3;
  T slots_[3];
  uint8_t write_ = 0;               // owned by the writer
  std::atomic<uint8_t> middle_{1};  // shared: index | kFresh
  uint8_t read_ = 2;                // owned by the reader
};

}  // namespace marionette::runtime
