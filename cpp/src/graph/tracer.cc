#include "marionette/graph/tracer.h"

#include <fstream>

namespace marionette::graph {

Tracer::Tracer(std::string name, int capacity, std::vector<const SignalBase*> signals)
    : Entity(std::move(name)), capacity_(capacity), traced_(std::move(signals)) {
  if (capacity_ < 1) throw GraphError("tracer '" + this->name() + "': capacity must be >= 1");
  for (const SignalBase* s : traced_) {
    if (s == nullptr) throw GraphError("tracer '" + this->name() + "': null signal");
    offsets_.push_back(row_width_);
    row_width_ += s->shape().size();
  }
  buffer_.assign(static_cast<size_t>(capacity_) * row_width_, 0.0);
  DeclareUpdate("record", &Tracer::Record, traced_);
}

void Tracer::Record(const Tick& t) const {
  double* row = buffer_.data() + static_cast<size_t>(head_) * row_width_;
  row[0] = static_cast<double>(t.index);
  row[1] = t.time;
  for (size_t i = 0; i < traced_.size(); ++i) {
    const_cast<SignalBase*>(traced_[i])->Pull(t);
    traced_[i]->Flatten(row + offsets_[i]);
  }
  head_ = (head_ + 1) % capacity_;
  if (size_ < capacity_) ++size_;
}

std::vector<std::string> Tracer::column_names() const {
  std::vector<std::string> names = {"tick", "time"};
  for (const SignalBase* s : traced_) {
    const int n = s->shape().size();
    for (int i = 0; i < n; ++i) {
      names.push_back(n == 1 ? s->full_name() : s->full_name() + "[" + std::to_string(i) + "]");
    }
  }
  return names;
}

std::vector<double> Tracer::Row(int i) const {
  if (i < 0 || i >= size_) {
    throw GraphError("tracer '" + name() + "': row " + std::to_string(i) + " out of range [0, " +
                     std::to_string(size_) + ")");
  }
  const int oldest = (head_ - size_ + capacity_) % capacity_;
  const double* row = buffer_.data() + static_cast<size_t>((oldest + i) % capacity_) * row_width_;
  return std::vector<double>(row, row + row_width_);
}

void Tracer::WriteCsv(const std::string& path) const {
  std::ofstream out(path);
  if (!out) throw GraphError("tracer '" + name() + "': cannot write " + path);
  const std::vector<std::string> names = column_names();
  for (size_t i = 0; i < names.size(); ++i) out << (i ? "," : "") << names[i];
  out << '\n';
  out.precision(17);
  for (int r = 0; r < size_; ++r) {
    const std::vector<double> row = Row(r);
    for (size_t i = 0; i < row.size(); ++i) out << (i ? "," : "") << row[i];
    out << '\n';
  }
}

}  // namespace marionette::graph
