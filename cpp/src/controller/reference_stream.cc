#include "marionette/controller/reference_stream.h"

#include <Eigen/Geometry>
#include <cmath>

namespace marionette::controller {
namespace {
constexpr double kUsToS = 1e-6;

int64_t TickUs(const graph::Tick& t) { return static_cast<int64_t>(std::llround(t.time * 1e6)); }
}  // namespace

ReferenceStream::ReferenceStream(std::string name, Kind kind, const Eigen::VectorXd& initial,
                                 int derivative_size, int capacity_samples, int max_chunk_samples,
                                 int queue_capacity)
    : Entity(std::move(name)),
      se3_(kind == Kind::kSe3),
      value_size_(static_cast<int>(initial.size())),
      derivative_size_(derivative_size),
      capacity_(capacity_samples),
      max_chunk_samples_(max_chunk_samples),
      initial_(initial),
      queue_(queue_capacity) {
  if (se3_ && value_size_ != 7) {
    throw graph::GraphError("reference stream '" + this->name() +
                            "': an SE3 stream holds 7 values "
                            "(x y z qw qx qy qz), got " +
                            std::to_string(value_size_));
  }
  if (capacity_ < 2 || max_chunk_samples_ < 1 || max_chunk_samples_ > capacity_) {
    throw graph::GraphError(
        "reference stream '" + this->name() +
        "': needs 1 <= max_chunk_samples <= capacity_samples and capacity >= 2");
  }
  popped_.values.reserve(static_cast<size_t>(max_chunk_samples_) * value_size_);
  popped_.derivatives.reserve(static_cast<size_t>(max_chunk_samples_) * derivative_size_);
  values_.assign(static_cast<size_t>(capacity_) * value_size_, 0.0);
  derivatives_.assign(static_cast<size_t>(capacity_) * derivative_size_, 0.0);
  DeclarePoll("receive", &ReferenceStream::Poll);
  value_ = &DeclareOutput<Eigen::VectorXd>("value", initial_, &ReferenceStream::CalcValue, {});
  derivative_ = &DeclareOutput<Eigen::VectorXd>(
      "derivative", Eigen::VectorXd::Zero(derivative_size_), &ReferenceStream::CalcDerivative, {});
  age_ = &DeclareOutput<double>("age", 0.0, &ReferenceStream::CalcAge, {});
  ended_ = &DeclareOutput<bool>("ended", false, &ReferenceStream::CalcEnded, {});
  if (se3_) {
    pose_ = &DeclareOutput<pinocchio::SE3>("pose", pinocchio::SE3::Identity(),
                                           &ReferenceStream::CalcPose, {value_});
  }
}

std::string ReferenceStream::ValidateChunk(const ReferenceChunk& c) const {
  if (c.num_samples < 1) return "no samples";
  if (c.num_samples > max_chunk_samples_) {
    return std::to_string(c.num_samples) + " samples in one chunk, at most " +
           std::to_string(max_chunk_samples_);
  }
  if (c.dt_us <= 0) return "non-positive dt_us " + std::to_string(c.dt_us);
  if (pushed_dt_us_ != 0 && c.dt_us != pushed_dt_us_) {
    return "dt_us " + std::to_string(c.dt_us) + " differs from the stream's " +
           std::to_string(pushed_dt_us_);
  }
  if (c.sequence < 0) return "negative sequence " + std::to_string(c.sequence);
  if (c.sequence > 0 && c.sequence != pushed_sequence_ + 1) {
    return "chunk " + std::to_string(c.sequence) + " of a reference whose chunk " +
           std::to_string(c.sequence - 1) + " never came (" +
           (pushed_sequence_ < 0 ? std::string("none taken")
                                 : "last taken " + std::to_string(pushed_sequence_)) +
           "); the stream holds its last sample";
  }
  if (c.values.size() != static_cast<size_t>(c.num_samples) * value_size_) {
    return "values have " + std::to_string(c.values.size()) + " entries, expected " +
           std::to_string(c.num_samples) + " x " + std::to_string(value_size_);
  }
  if (c.derivatives.size() != static_cast<size_t>(c.num_samples) * derivative_size_) {
    return "derivatives have " + std::to_string(c.derivatives.size()) + " entries, expected " +
           std::to_string(c.num_samples) + " x " + std::to_string(derivative_size_);
  }
  for (double x : c.values) {
    if (!std::isfinite(x)) return "non-finite value";
  }
  for (double x : c.derivatives) {
    if (!std::isfinite(x)) return "non-finite derivative";
  }
  if (se3_) {
    for (int i = 0; i < c.num_samples; ++i) {
      const double* v = &c.values[static_cast<size_t>(i) * 7];
      const double norm = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5] + v[6] * v[6]);
      if (std::abs(norm - 1.0) > 1e-3) {
        return "sample " + std::to_string(i) + " has a quaternion of norm " + std::to_string(norm);
      }
    }
  }
  return "";
}

void ReferenceStream::SetInitial(const Eigen::VectorXd& initial) {
  if (initial.size() != value_size_) {
    throw graph::GraphError("reference stream '" + name() + "': initial value of size " +
                            std::to_string(initial.size()) + ", expected " +
                            std::to_string(value_size_));
  }
  initial_ = initial;
}

bool ReferenceStream::Push(const ReferenceChunk& chunk) {
  if (!queue_.Push(chunk)) {
    dropped_.fetch_add(1);
    return false;
  }
  pushed_dt_us_ = chunk.dt_us;
  pushed_sequence_ = chunk.sequence;
  return true;
}

void ReferenceStream::Poll(const graph::Tick&) {
  if (!polled_before_tick_) drained_count_ = 0;
  polled_before_tick_ = false;
  Drain();
}

void ReferenceStream::PollBeforeTick() {
  if (!polled_before_tick_) drained_count_ = 0;
  polled_before_tick_ = true;
  Drain();
}

void ReferenceStream::Drain() {
  while (queue_.Pop(&popped_)) {
    const ReferenceChunk& c = popped_;
    if (drained_count_ < static_cast<int>(drained_hashes_.size())) {
      drained_hashes_[drained_count_++] = c.source_hash;
    }
    if (dt_us_ == 0) {
      dt_us_ = c.dt_us;
      origin_us_ = c.start_us;
      begin_ = end_ = 0;
    }
    // First absolute sample index of the chunk (chunks are aligned on the stream's grid).
    const int64_t k0 = (c.start_us - origin_us_) / dt_us_;
    const int64_t k1 = k0 + c.num_samples;
    if (k1 <= begin_) continue;  // entirely in the past of what we keep
    for (int64_t k = k0; k < k1; ++k) {
      const int64_t slot = ((k % capacity_) + capacity_) % capacity_;
      const int i = static_cast<int>(k - k0);
      std::copy_n(&c.values[static_cast<size_t>(i) * value_size_], value_size_,
                  &values_[static_cast<size_t>(slot) * value_size_]);
      std::copy_n(&c.derivatives[static_cast<size_t>(i) * derivative_size_], derivative_size_,
                  &derivatives_[static_cast<size_t>(slot) * derivative_size_]);
    }
    // The chunk defines the future from k0 on; keep older samples only if contiguous.
    if (end_ == begin_ || k0 > end_ || k0 < begin_) begin_ = k0;
    end_ = k1;
    begin_ = std::max(begin_, end_ - capacity_);
    ends_ = c.last;
  }
}

void ReferenceStream::Locate(int64_t time_us, int64_t* k, double* fraction) const {
  const double position = static_cast<double>(time_us - origin_us_) / dt_us_;
  const int64_t kf = static_cast<int64_t>(std::floor(position));
  if (kf < begin_) {
    *k = begin_;
    *fraction = 0.0;
  } else if (kf >= end_ - 1) {
    *k = end_ - 1;
    *fraction = 0.0;
  } else {
    *k = kf;
    *fraction = position - kf;
  }
}

void ReferenceStream::CalcValue(const graph::Tick& t, Eigen::VectorXd* out) const {
  if (end_ == begin_) {
    *out = initial_;
    return;
  }
  int64_t k;
  double f;
  Locate(TickUs(t), &k, &f);
  const double* a = &values_[static_cast<size_t>(k % capacity_) * value_size_];
  const Eigen::Map<const Eigen::VectorXd> va(a, value_size_);
  if (f == 0.0) {
    *out = va;
    return;
  }
  const Eigen::Map<const Eigen::VectorXd> vb(
      &values_[static_cast<size_t>((k + 1) % capacity_) * value_size_], value_size_);
  *out = (1.0 - f) * va + f * vb;
  if (se3_) {  // rotation part by slerp, stored as (w, x, y, z)
    const Eigen::Quaterniond qa(a[3], a[4], a[5], a[6]), qb(vb[3], vb[4], vb[5], vb[6]);
    const Eigen::Quaterniond q = qa.slerp(f, qb);
    (*out)[3] = q.w(), (*out)[4] = q.x(), (*out)[5] = q.y(), (*out)[6] = q.z();
  }
}

void ReferenceStream::CalcDerivative(const graph::Tick& t, Eigen::VectorXd* out) const {
  if (end_ == begin_ || derivative_size_ == 0) {
    out->setZero();
    return;
  }
  int64_t k;
  double f;
  Locate(TickUs(t), &k, &f);
  const Eigen::Map<const Eigen::VectorXd> da(
      &derivatives_[static_cast<size_t>(k % capacity_) * derivative_size_], derivative_size_);
  if (f == 0.0) {
    // Past the last sample the reference is held: no feed-forward.
    if (TickUs(t) > origin_us_ + (end_ - 1) * dt_us_) {
      out->setZero();
    } else {
      *out = da;
    }
    return;
  }
  const Eigen::Map<const Eigen::VectorXd> db(
      &derivatives_[static_cast<size_t>((k + 1) % capacity_) * derivative_size_], derivative_size_);
  *out = (1.0 - f) * da + f * db;
}

void ReferenceStream::CalcAge(const graph::Tick& t, double* out) const {
  if (end_ == begin_) {
    *out = 0.0;  // holding the initial value is not stale: nothing was promised yet
    return;
  }
  const int64_t last_us = origin_us_ + (end_ - 1) * dt_us_;
  *out = std::max<int64_t>(0, TickUs(t) - last_us) * kUsToS;
}

bool ReferenceStream::Starved(int64_t time_us) const {
  if (ends_ || (end_ > begin_ && time_us <= origin_us_ + (end_ - 1) * dt_us_)) return false;
  return queue_.Front() == nullptr;
}

void ReferenceStream::CalcEnded(const graph::Tick& t, bool* out) const {
  *out = ends_ && end_ > begin_ && TickUs(t) >= origin_us_ + (end_ - 1) * dt_us_;
}

void ReferenceStream::CalcPose(const graph::Tick& t, pinocchio::SE3* out) const {
  const Eigen::VectorXd& v = value_->Eval(t);
  out->translation() = v.head<3>();
  out->rotation() = Eigen::Quaterniond(v[3], v[4], v[5], v[6]).normalized().toRotationMatrix();
}

}  // namespace marionette::controller
