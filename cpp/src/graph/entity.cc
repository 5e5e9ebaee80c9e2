#include "marionette/graph/entity.h"

#include <algorithm>

namespace marionette::graph {

Entity::Entity(std::string name) : name_(std::move(name)) {
  if (name_.empty() || name_.find('.') != std::string::npos) {
    throw GraphError("invalid entity name '" + name_ + "': non-empty, without '.'");
  }
}

Entity::~Entity() = default;

std::vector<InputSignalBase*> Entity::inputs() const {
  std::vector<InputSignalBase*> result;
  for (const auto& s : signals_) {
    if (s->is_input()) result.push_back(static_cast<InputSignalBase*>(s.get()));
  }
  return result;
}

std::vector<SignalBase*> Entity::outputs() const {
  std::vector<SignalBase*> result;
  for (const auto& s : signals_) {
    if (!s->is_input()) result.push_back(s.get());
  }
  return result;
}

SignalBase* Entity::FindSignal(std::string_view name) const {
  for (const auto& s : signals_) {
    if (s->name() == name) return s.get();
  }
  return nullptr;
}

SignalBase& Entity::signal(std::string_view name) const {
  if (SignalBase* s = FindSignal(name)) return *s;
  std::string known;
  for (const auto& s : signals_) known += (known.empty() ? "" : ", ") + s->name();
  throw GraphError("entity '" + name_ + "' (" + type_name() + ") has no signal '" +
                   std::string(name) + "'; its signals: " + known);
}

void Entity::CheckNewSignalName(const std::string& name) const {
  if (name.empty() || name.find('.') != std::string::npos) {
    throw GraphError("entity '" + name_ + "': invalid signal name '" + name + "'");
  }
  if (FindSignal(name) != nullptr) {
    throw GraphError("entity '" + name_ + "': signal '" + name + "' declared twice");
  }
}

void Entity::CheckPrerequisites(const std::string& signal,
                                const std::vector<const SignalBase*>& prerequisites,
                                bool own_signals_only) const {
  for (const SignalBase* p : prerequisites) {
    if (p == nullptr) {
      throw GraphError("entity '" + name_ + "': null prerequisite of '" + signal + "'");
    }
    if (own_signals_only && &p->owner() != this) {
      throw GraphError("entity '" + name_ + "': '" + signal + "' declares " + p->full_name() +
                       " as a prerequisite; an output may only depend on its own entity's "
                       "signals (plug an input instead)");
    }
  }
}

namespace internal {
void ThrowWrongSignal(const Entity& entity, std::string_view name, const char* wanted,
                      const SignalBase& found) {
  throw GraphError("signal " + entity.name() + "." + std::string(name) + " is a " +
                   ToString(found.kind()) + " of type " + found.type_name() + ", not the " +
                   wanted + " asked for");
}
}  // namespace internal

}  // namespace marionette::graph
