#pragma once
/// Entities: the nodes of the dynamic graph (SoT's Entity, Drake's LeafSystem discipline).
///
/// An entity declares all its signals in its constructor, with the prerequisites of each output;
/// nothing is wired after construction except plugs between entities (GraphBuilder). Calc and
/// update callbacks are const member functions that read inputs through Eval(t) and write only
/// their output argument (STYLE.md §5 rules 1–3).

#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "marionette/graph/signal.h"

namespace marionette::graph {

/// A state of an entity: value x_t during tick t, x_{t+1} = update(t, x_t) committed after the
/// tick. Type-erased so the graph can run all updates, then commit all.
class StateSlot {
 public:
  virtual ~StateSlot() = default;
  virtual SignalBase& signal() = 0;
  /// Computes the next value from the current tick's inputs (phase 1 of Graph::Evaluate).
  virtual void ComputeNext(const Tick& t) = 0;
  /// Makes the next value current (phase 2).
  virtual void Commit() = 0;
  /// The signals the update reads (for validation and drawing; not a same-tick dependency).
  const std::vector<const SignalBase*>& prerequisites() const { return prerequisites_; }

 protected:
  explicit StateSlot(std::vector<const SignalBase*> prerequisites)
      : prerequisites_(std::move(prerequisites)) {}

 private:
  std::vector<const SignalBase*> prerequisites_;
};

/// A callback run at the start of every tick, before anything is evaluated: it brings data from
/// outside the graph (LCM mailboxes, sensors) into its entity's buffers and source outputs.
struct PollHook {
  Entity* owner;
  std::string name;
  std::function<void(const Tick&)> run;
};

/// A callback run once per tick after evaluation: tracers, publishers, devices pulling their
/// command. It reads signals through Eval(t) and writes only its entity's private buffers.
struct UpdateHook {
  Entity* owner;
  std::string name;
  std::function<void(const Tick&)> run;
  std::vector<const SignalBase*> prerequisites;
};

class Entity {
 public:
  explicit Entity(std::string name);
  Entity(const Entity&) = delete;
  Entity& operator=(const Entity&) = delete;
  virtual ~Entity();

  const std::string& name() const { return name_; }
  /// The class name shown by introspection ("FeaturePosture").
  virtual const char* type_name() const = 0;

  const std::vector<std::unique_ptr<SignalBase>>& signals() const { return signals_; }
  std::vector<InputSignalBase*> inputs() const;
  std::vector<SignalBase*> outputs() const;
  const std::vector<std::unique_ptr<StateSlot>>& states() const { return states_; }
  const std::vector<UpdateHook>& update_hooks() const { return update_hooks_; }
  const std::vector<PollHook>& poll_hooks() const { return poll_hooks_; }

  /// The signal called `name`, or nullptr.
  SignalBase* FindSignal(std::string_view name) const;

  /// Compute-time budget of this entity per tick [us] (0 = none); checked when the graph
  /// profiles (Graph::SetProfiling). Call between ticks.
  void set_time_budget_us(double budget_us) { timing_.budget_ns = 1e3 * budget_us; }
  double time_budget_us() const { return 1e-3 * timing_.budget_ns; }
  /// What the graph measured of this entity (valid when profiling).
  const EntityTiming& timing() const { return timing_; }
  EntityTiming& mutable_timing() { return timing_; }
  /// The signal called `name`; throws GraphError listing this entity's signals otherwise.
  SignalBase& signal(std::string_view name) const;
  /// Typed access; throws GraphError on an unknown name or a different kind or type.
  template <typename T>
  InputSignal<T>& input(std::string_view name) const;
  template <typename T>
  OutputSignal<T>& output(std::string_view name) const;

 protected:
  /// An input that must be plugged or set before Build(); `model` fixes its type and shape.
  template <typename T>
  InputSignal<T>& DeclareInput(std::string name, T model, bool settable = false);
  /// An input holding `default_value` until plugged or set (a parameter, e.g. a gain).
  template <typename T>
  InputSignal<T>& DeclareParameter(std::string name, T default_value, bool settable = true);
  /// An output computed by `calc` from `prerequisites` (signals of this entity).
  template <typename T, typename E>
  OutputSignal<T>& DeclareOutput(std::string name, T model, void (E::*calc)(const Tick&, T*) const,
                                 std::vector<const SignalBase*> prerequisites);
  /// An output written by this entity between ticks (e.g. a device's sensors).
  template <typename T>
  OutputSignal<T>& DeclareSource(std::string name, T model);
  /// A state output: x_t during tick t; x_{t+1} = update(t, x_t) after the tick.
  template <typename T, typename E>
  OutputSignal<T>& DeclareState(std::string name, T initial,
                                void (E::*update)(const Tick&, const T& current, T* next) const,
                                std::vector<const SignalBase*> prerequisites);
  /// A callback run once per tick after the graph's evaluation.
  template <typename E>
  void DeclareUpdate(std::string name, void (E::*update)(const Tick&) const,
                     std::vector<const SignalBase*> prerequisites);
  /// A callback run at the start of every tick, before evaluation, that may change this
  /// entity's buffers and source outputs (it is the only non-const callback).
  template <typename E>
  void DeclarePoll(std::string name, void (E::*poll)(const Tick&));

 private:
  void CheckNewSignalName(const std::string& name) const;
  // Outputs and states depend on their own entity's signals only; update hooks may read any.
  void CheckPrerequisites(const std::string& signal,
                          const std::vector<const SignalBase*>& prerequisites,
                          bool own_signals_only) const;

  std::string name_;
  std::vector<std::unique_ptr<SignalBase>> signals_;
  std::vector<std::unique_ptr<StateSlot>> states_;
  std::vector<UpdateHook> update_hooks_;
  std::vector<PollHook> poll_hooks_;
  EntityTiming timing_;
};

// ----------------------------------------------------------------------------------------------

namespace internal {
template <typename T>
class TypedStateSlot final : public StateSlot {
 public:
  using Update = std::function<void(const Tick&, const T&, T*)>;
  TypedStateSlot(OutputSignal<T>* signal, Update update,
                 std::vector<const SignalBase*> prerequisites)
      : StateSlot(std::move(prerequisites)),
        signal_(signal),
        next_(signal->value()),
        update_(std::move(update)) {}
  SignalBase& signal() override { return *signal_; }
  void ComputeNext(const Tick& t) override { update_(t, signal_->value(), &next_); }
  void Commit() override { std::swap(signal_->mutable_value(), next_); }

 private:
  OutputSignal<T>* signal_;
  T next_;  // same shape as the signal: the swap never allocates
  Update update_;
};

[[noreturn]] void ThrowWrongSignal(const Entity& entity, std::string_view name, const char* wanted,
                                   const SignalBase& found);
}  // namespace internal

template <typename T>
InputSignal<T>& Entity::input(std::string_view name) const {
  SignalBase& s = signal(name);
  if (s.kind() != SignalKind::kInput || s.type() != typeid(T)) {
    internal::ThrowWrongSignal(*this, name, ValueTraits<T>::kName, s);
  }
  return static_cast<InputSignal<T>&>(s);
}

template <typename T>
OutputSignal<T>& Entity::output(std::string_view name) const {
  SignalBase& s = signal(name);
  if (s.kind() == SignalKind::kInput || s.type() != typeid(T)) {
    internal::ThrowWrongSignal(*this, name, ValueTraits<T>::kName, s);
  }
  return static_cast<OutputSignal<T>&>(s);
}

template <typename T>
InputSignal<T>& Entity::DeclareInput(std::string name, T model, bool settable) {
  CheckNewSignalName(name);
  auto input = std::make_unique<InputSignal<T>>(this, std::move(name), std::move(model),
                                                /*fixed=*/false, settable);
  InputSignal<T>& ref = *input;
  signals_.push_back(std::move(input));
  return ref;
}

template <typename T>
InputSignal<T>& Entity::DeclareParameter(std::string name, T default_value, bool settable) {
  CheckNewSignalName(name);
  auto input = std::make_unique<InputSignal<T>>(this, std::move(name), std::move(default_value),
                                                /*fixed=*/true, settable);
  InputSignal<T>& ref = *input;
  signals_.push_back(std::move(input));
  return ref;
}

template <typename T, typename E>
OutputSignal<T>& Entity::DeclareOutput(std::string name, T model,
                                       void (E::*calc)(const Tick&, T*) const,
                                       std::vector<const SignalBase*> prerequisites) {
  CheckNewSignalName(name);
  CheckPrerequisites(name, prerequisites, /*own_signals_only=*/true);
  const E* self = static_cast<const E*>(this);
  auto output = std::make_unique<OutputSignal<T>>(
      this, std::move(name), SignalKind::kOutput, std::move(model),
      [self, calc](const Tick& t, T* out) { (self->*calc)(t, out); }, std::move(prerequisites));
  OutputSignal<T>& ref = *output;
  signals_.push_back(std::move(output));
  return ref;
}

template <typename T>
OutputSignal<T>& Entity::DeclareSource(std::string name, T model) {
  CheckNewSignalName(name);
  auto output = std::make_unique<OutputSignal<T>>(this, std::move(name), SignalKind::kSource,
                                                  std::move(model), nullptr,
                                                  std::vector<const SignalBase*>{});
  OutputSignal<T>& ref = *output;
  signals_.push_back(std::move(output));
  return ref;
}

template <typename T, typename E>
OutputSignal<T>& Entity::DeclareState(std::string name, T initial,
                                      void (E::*update)(const Tick&, const T&, T*) const,
                                      std::vector<const SignalBase*> prerequisites) {
  CheckNewSignalName(name);
  CheckPrerequisites(name, prerequisites, /*own_signals_only=*/true);
  // The state's value does not depend on the prerequisites within a tick (they feed the next
  // value): the signal itself has none, the update keeps them for drawing and validation.
  auto output = std::make_unique<OutputSignal<T>>(this, std::move(name), SignalKind::kState,
                                                  std::move(initial), nullptr,
                                                  std::vector<const SignalBase*>{});
  OutputSignal<T>& ref = *output;
  signals_.push_back(std::move(output));
  const E* self = static_cast<const E*>(this);
  states_.push_back(std::make_unique<internal::TypedStateSlot<T>>(
      &ref, [self, update](const Tick& t, const T& x, T* next) { (self->*update)(t, x, next); },
      std::move(prerequisites)));
  return ref;
}

template <typename E>
void Entity::DeclareUpdate(std::string name, void (E::*update)(const Tick&) const,
                           std::vector<const SignalBase*> prerequisites) {
  CheckPrerequisites(name, prerequisites, /*own_signals_only=*/false);
  const E* self = static_cast<const E*>(this);
  update_hooks_.push_back(UpdateHook{this, std::move(name),
                                     [self, update](const Tick& t) { (self->*update)(t); },
                                     std::move(prerequisites)});
}

template <typename E>
void Entity::DeclarePoll(std::string name, void (E::*poll)(const Tick&)) {
  E* self = static_cast<E*>(this);
  poll_hooks_.push_back(
      PollHook{this, std::move(name), [self, poll](const Tick& t) { (self->*poll)(t); }});
}

}  // namespace marionette::graph
