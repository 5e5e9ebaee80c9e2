#include "marionette/controller/graph_service.h"

#include <sstream>

namespace marionette::controller {

GraphService::GraphService()
    : samples_(4096, WatchSample{-1, 0, -1, std::vector<double>(kMaxWatchedValues)}), sets_(256) {}

GraphService::~GraphService() = default;

// ---- loop thread ---------------------------------------------------------------------------

int GraphService::ApplySets(int64_t* hashes, int max) {
  // The watch is taken here, before the sets, not where it is sampled: a `get` posted after a
  // `set` then sees the set applied. Taken at the end of the tick, a watch posted between this
  // tick's sets and its sample read the value from before a set queued ahead of it.
  if (Watch* next = posted_.exchange(nullptr, std::memory_order_acq_rel)) {
    if (active_ != nullptr) retired_.Push(active_);
    active_ = next->signals.empty() ? nullptr : next;
    if (active_ == nullptr) retired_.Push(next);
  }
  int n = 0;
  SetRequest r;
  while (n < max && sets_.Pop(&r)) {
    r.input->SetFlat(r.values.data(), r.size);
    hashes[n++] = r.hash;
  }
  return n;
}

void GraphService::Sample(int64_t tick, int64_t utime) {
  if (active_ == nullptr) return;
  // Filled in place in the queue (slots are preallocated at the largest size): only the watched
  // values are written. A full queue drops the sample (the LCM thread is behind).
  WatchSample* s = samples_.PushSlot();
  if (s == nullptr) return;
  s->tick = tick;
  s->utime = utime;
  s->watch_id = active_->id;
  for (size_t i = 0; i < active_->signals.size(); ++i) {
    active_->signals[i]->Flatten(s->values.data() + active_->offsets[i]);
  }
  samples_.CommitPush();
}

void GraphService::Invalidate() {
  if (active_ != nullptr) {
    retired_.Push(active_);
    active_ = nullptr;
  }
  if (Watch* pending = posted_.exchange(nullptr, std::memory_order_acq_rel)) retired_.Push(pending);
  invalidated_.store(true, std::memory_order_release);
}

// ---- LCM thread ----------------------------------------------------------------------------

int64_t GraphService::SetWatch(std::vector<graph::SignalBase*> signals) {
  auto watch = std::make_unique<Watch>();
  watch->id = next_id_++;
  for (graph::SignalBase* s : signals) {
    watch->offsets.push_back(watch->total_size);
    watch->total_size += s->shape().size();
  }
  if (watch->total_size > kMaxWatchedValues) {
    throw std::invalid_argument("watching " + std::to_string(watch->total_size) +
                                " values, at most " + std::to_string(kMaxWatchedValues));
  }
  watch->signals = std::move(signals);
  Watch* raw = watch.get();
  owned_[raw->id] = std::move(watch);
  if (Watch* unseen = posted_.exchange(raw, std::memory_order_acq_rel)) owned_.erase(unseen->id);
  return raw->id;
}

const Watch* GraphService::FindWatch(int64_t id) const {
  auto it = owned_.find(id);
  return it == owned_.end() ? nullptr : it->second.get();
}

const WatchSample* GraphService::FrontSample() const { return samples_.Front(); }
void GraphService::PopSample() { samples_.PopFront(); }

std::string GraphService::QueueSet(graph::SignalBase& signal, const std::vector<double>& values,
                                   int64_t hash) {
  if (!signal.is_input()) return signal.full_name() + " is an output: only inputs can be set";
  auto& input = static_cast<graph::InputSignalBase&>(signal);
  if (!input.settable()) {
    return signal.full_name() +
           " is not settable (only inputs declared settable, e.g. gains, can be "
           "changed while running)";
  }
  if (input.is_plugged()) {
    return signal.full_name() + " is plugged to " + input.source()->full_name() +
           ": its value comes from there";
  }
  const int size = signal.shape().size();
  if (static_cast<int>(values.size()) != size) {
    return signal.full_name() + " takes " + std::to_string(size) + " values, " +
           std::to_string(values.size()) + " given";
  }
  if (size > kMaxSetSize)
    return signal.full_name() + " is too large to set (" + std::to_string(size) + ")";
  for (double v : values) {
    if (!std::isfinite(v)) return "non-finite value for " + signal.full_name();
  }
  SetRequest r;
  r.input = &input;
  r.hash = hash;
  r.size = size;
  std::copy(values.begin(), values.end(), r.values.begin());
  if (!sets_.Push(r)) return "too many pending sets";
  return "";
}

void GraphService::CollectGarbage() {
  Watch* w = nullptr;
  while (retired_.Pop(&w)) owned_.erase(w->id);
  invalidated_.store(false, std::memory_order_release);
}

std::string ListGraph(const graph::Graph& g) {
  std::ostringstream os;
  for (const auto& e : g.entities()) {
    os << e->name() << " (" << e->type_name() << ")";
    if (e->time_budget_us() > 0.0) os << "  budget " << e->time_budget_us() << " us";
    os << "\n";
    for (const auto& s : e->signals()) {
      const graph::Shape shape = s->shape();
      os << "  " << graph::ToString(s->kind()) << " " << s->name() << " : " << s->type_name() << " "
         << shape.rows << "x" << shape.cols;
      if (s->is_input()) {
        const auto& in = static_cast<const graph::InputSignalBase&>(*s);
        if (in.is_plugged()) {
          os << " <- " << in.source()->full_name();
        } else {
          os << " (fixed)";
        }
        if (in.settable()) os << " [settable]";
      }
      os << "\n";
    }
  }
  return os.str();
}

}  // namespace marionette::controller
