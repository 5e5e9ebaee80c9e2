#include "marionette/graph/signal.h"

#include "marionette/graph/entity.h"

namespace marionette::graph {

const char* ToString(SignalKind kind) {
  switch (kind) {
    case SignalKind::kInput:
      return "input";
    case SignalKind::kOutput:
      return "output";
    case SignalKind::kSource:
      return "source";
    case SignalKind::kState:
      return "state";
  }
  return "?";
}

std::string SignalBase::full_name() const { return owner_->name() + "." + name_; }

namespace {
std::string Describe(const SignalBase& s) {
  const Shape shape = s.shape();
  return std::string(ToString(s.kind())) + " " + s.full_name() + " (" + s.type_name() + " " +
         std::to_string(shape.rows) + "x" + std::to_string(shape.cols) + ")";
}
}  // namespace

void CheckPluggable(const SignalBase& output, const SignalBase& input) {
  if (output.is_input()) {
    throw GraphError("cannot plug " + Describe(input) + " to " + Describe(output) +
                     ": the source must be an output");
  }
  if (!input.is_input()) {
    throw GraphError("cannot plug " + Describe(input) + " to " + Describe(output) +
                     ": the destination must be an input");
  }
  if (output.type() != input.type()) {
    throw GraphError("type mismatch: " + Describe(output) + " cannot feed " + Describe(input));
  }
  if (output.shape() != input.shape()) {
    throw GraphError("shape mismatch: " + Describe(output) + " cannot feed " + Describe(input));
  }
}

}  // namespace marionette::graph
