#pragma once
/// SpscQueue<T>: a bounded lock-free queue between one producer and one consumer thread. The
/// storage is allocated once; Push never blocks (it returns false when full and the caller
/// counts the drop).

#include <atomic>
#include <cstddef>
#include <vector>

namespace marionette::runtime {

template <typename T>
class SpscQueue {
 public:
  explicit SpscQueue(size_t capacity) : buffer_(capacity + 1) {}
  /// Every slot starts as a copy of `model`: items of the model's sizes are then copied in and
  /// out without allocation.
  SpscQueue(size_t capacity, const T& model) : buffer_(capacity + 1, model) {}

  /// Producer side. False when the queue is full (the item is not queued).
  bool Push(const T& item) {
    const size_t head = head_.load(std::memory_order_relaxed);
    const size_t next = Next(head);
    if (next == tail_.load(std::memory_order_acquire)) return false;
    buffer_[head] = item;
    head_.store(next, std::memory_order_release);
    return true;
  }

  /// Producer side, in place: the slot to fill, or nullptr when full; CommitPush() queues it.
  /// Lets large items be written field by field instead of copied whole.
  T* PushSlot() {
    const size_t head = head_.load(std::memory_order_relaxed);
    if (Next(head) == tail_.load(std::memory_order_acquire)) return nullptr;
    return &buffer_[head];
  }
  void CommitPush() {
    head_.store(Next(head_.load(std::memory_order_relaxed)), std::memory_order_release);
  }

  /// Consumer side, in place: the oldest item, or nullptr when empty; PopFront() releases it.
  const T* Front() const {
    const size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_.load(std::memory_order_acquire)) return nullptr;
    return &buffer_[tail];
  }
  void PopFront() {
    tail_.store(Next(tail_.load(std::memory_order_relaxed)), std::memory_order_release);
  }

  /// Consumer side. False when empty.
  bool Pop(T* item) {
    const size_t tail = tail_.load(std::memory_order_relaxed);
    if (tail == head_.load(std::memory_order_acquire)) return false;
    *item = buffer_[tail];
    tail_.store(Next(tail), std::memory_order_release);
    return true;
  }

  size_t capacity() const { return buffer_.size() - 1; }

 private:
  size_t Next(size_t i) const { return i + 1 == buffer_.size() ? 0 : i + 1; }
  std::vector<T> buffer_;
  alignas(64) std::atomic<size_t> head_{0};
  alignas(64) std::atomic<size_t> tail_{0};
};

}  // namespace marionette::runtime
