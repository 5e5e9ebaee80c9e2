#pragma once
/// ReferenceStream: a task reference streamed from another process (lcmt_task_reference on
/// TASK_REFERENCE), sampled at the controller's tick.
///
/// The LCM thread translates each message into a ReferenceChunk and Push()es it into a bounded
/// lock-free queue; at each tick the stream's poll hook drains the queue into its sample buffer
/// (before anything is evaluated) and the outputs give
/// the reference at the tick's time (linear interpolation; quaternions by slerp). A chunk
/// replaces every sample from its start on (a replanned future wins). Before the first sample
/// the stream holds its initial value; after the last one it holds the last sample and its
/// `age` grows — the controller's watchdog holds the robot when the age exceeds its timeout.
/// A chunk numbered n > 0 follows chunk n - 1 of its reference (lcmt_task_reference.sequence);
/// when that one was never taken (lost on the way, or refused) ValidateChunk refuses it too:
/// playing it would jump the robot ahead along its plan, holding the last sample lets the
/// watchdog hold it instead.
/// @entity  inputs: none (fed by Push from the LCM thread)
///          outputs: value (value_size), derivative (derivative_size),
///                   age (double, s past the last sample, 0 inside), ended (bool),
///                   pose (SE3, only when value_size == 7: x y z qw qx qy qz)

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"
#include "marionette/runtime/spsc_queue.h"

namespace marionette::controller {

/// Samples of one chunk, row-major; capacity fixed at construction of the stream.
struct ReferenceChunk {
  int64_t start_us = 0;  // controller time of sample 0
  int64_t dt_us = 1000;
  int num_samples = 0;
  std::vector<double> values;       // num_samples x value_size
  std::vector<double> derivatives;  // num_samples x derivative_size (zeros when not given)
  bool last = false;                // the reference ends with this chunk
  int sequence = 0;                 // 0 starts a reference; n > 0 follows chunk n - 1
  int64_t source_hash = 0;          // names the message it came from (controller journal)
};

class ReferenceStream final : public graph::Entity {
 public:
  enum class Kind { kVector, kSe3 };
  /// `initial` (value_size; 7 for kSe3) is held until the first sample arrives.
  /// `capacity_samples` bounds the look-ahead kept (5000 = 5 s at 1 kHz); `max_chunk_samples`
  /// the size of one chunk. SE3 streams interpolate rotations by slerp and check unit quaternions.
  ReferenceStream(std::string name, Kind kind, const Eigen::VectorXd& initial, int derivative_size,
                  int capacity_samples = 5000, int max_chunk_samples = 1000,
                  int queue_capacity = 64);
  const char* type_name() const override { return "ReferenceStream"; }

  int value_size() const { return value_size_; }
  int derivative_size() const { return derivative_size_; }
  int max_chunk_samples() const { return max_chunk_samples_; }

  /// The value held until the first sample arrives (size value_size; no allocation: callable
  /// from the loop when the stream's controller is swapped in).
  void SetInitial(const Eigen::VectorXd& initial);

  /// LCM thread: a chunk with sizes matching this stream (checked by the caller, see
  /// ValidateChunk). Returns false when the queue is full (the chunk is dropped and counted).
  bool Push(const ReferenceChunk& chunk);
  /// LCM thread: why `chunk` cannot feed this stream ("" when it can): sizes, NaN, time step,
  /// unit quaternion, or a sequence number that does not follow the last chunk pushed.
  std::string ValidateChunk(const ReferenceChunk& chunk) const;
  int64_t dropped_chunks() const { return dropped_.load(); }
  /// Loop thread, between ticks: the stream does not cover `time_us` — the reference has not
  /// ended, no sample came yet or the last one is before `time_us`, and no chunk waits in the
  /// queue. An unpaced loop (simulated time) waits while this holds instead of ticking on.
  bool Starved(int64_t time_us) const;
  /// Loop thread, before tick t is evaluated (an unpaced loop waiting for this stream): drains
  /// the queue as the tick's Poll would, so that Starved sees what the chunks taken in cover (a
  /// chunk replaces the future from its start: a re-sent stretch that starts in the past may end
  /// it before t). The chunks count as drained at tick t (the journal records them there).
  void PollBeforeTick();
  /// Loop thread: the source_hash of the chunks the last poll took in (up to 64 per tick).
  int drained_count() const { return drained_count_; }
  int64_t drained_hash(int i) const { return drained_hashes_[i]; }

  graph::OutputSignal<Eigen::VectorXd>& value_output() { return *value_; }
  graph::OutputSignal<Eigen::VectorXd>& derivative_output() { return *derivative_; }
  graph::OutputSignal<double>& age_output() { return *age_; }
  graph::OutputSignal<bool>& ended_output() { return *ended_; }
  /// Only for SE3 streams; nullptr otherwise.
  graph::OutputSignal<pinocchio::SE3>* pose_output() { return pose_; }

 private:
  void Poll(const graph::Tick& t);  // drains the queue into the sample buffer
  // Index of the sample at or before time_us, and the interpolation fraction to the next one.
  void Locate(int64_t time_us, int64_t* k, double* fraction) const;
  void CalcValue(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcDerivative(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcAge(const graph::Tick& t, double* out) const;
  void CalcEnded(const graph::Tick& t, bool* out) const;
  void CalcPose(const graph::Tick& t, pinocchio::SE3* out) const;

  bool se3_;
  int value_size_;
  int derivative_size_;
  int capacity_;
  int max_chunk_samples_;
  Eigen::VectorXd initial_;
  runtime::SpscQueue<ReferenceChunk> queue_;
  ReferenceChunk popped_;  // preallocated pop target
  std::atomic<int64_t> dropped_{0};
  // The last chunk pushed (LCM thread only): its time step and sequence number.
  int64_t pushed_dt_us_ = 0;  // 0 until the first push
  int pushed_sequence_ = -1;  // -1 until the first push
  // Sample buffer: ring of `capacity_` samples, sample k (absolute) in slot k % capacity_,
  // valid for k in [begin_, end_). Written only by Poll (loop thread).
  std::vector<double> values_;       // capacity x value_size
  std::vector<double> derivatives_;  // capacity x derivative_size
  int64_t origin_us_ = 0;            // time of sample k = origin + k dt
  int64_t dt_us_ = 0;                // 0 until the first chunk
  int64_t begin_ = 0, end_ = 0;
  bool ends_ = false;  // the sample end_ - 1 is the last one
  std::array<int64_t, 64> drained_hashes_{};
  int drained_count_ = 0;
  bool polled_before_tick_ = false;  // PollBeforeTick drained for the coming tick
  void Drain();

  graph::OutputSignal<Eigen::VectorXd>* value_{};
  graph::OutputSignal<Eigen::VectorXd>* derivative_{};
  graph::OutputSignal<double>* age_{};
  graph::OutputSignal<bool>* ended_{};
  graph::OutputSignal<pinocchio::SE3>* pose_{};
};

}  // namespace marionette::controller
