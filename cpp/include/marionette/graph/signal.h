#pragma once
/// Signals: the typed, time-stamped values that flow between entities (dynamic-graph's
/// signals with Drake's discipline, STYLE.md §2).
///
/// - An `OutputSignal<T>` is computed by its entity's `Calc` from prerequisites declared at
///   construction, at most once per tick and only when pulled (`Eval(t)` recomputes only when
///   `t.index` is newer than the cached value's). Its buffer is allocated from the model value
///   at declaration, so evaluation never allocates.
/// - A *source* output has no `Calc`: its entity writes it between ticks (device sensors).
/// - A *state* output holds x_t during tick t; the graph computes x_{t+1} from its update
///   function after the tick's evaluation and commits it (delayed edge: no algebraic cycle).
/// - An `InputSignal<T>` is plugged to exactly one `OutputSignal<T>` of the same shape, or holds
///   a fixed value (SoT's constant signal, Drake's FixValue).

#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <typeindex>
#include <vector>

#include "marionette/graph/profiling.h"
#include "marionette/graph/tick.h"
#include "marionette/graph/value_traits.h"

namespace marionette::graph {

class Entity;

/// Raised for every wiring or value error: the message names the entities and signals involved.
class GraphError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class SignalKind { kInput, kOutput, kSource, kState };
const char* ToString(SignalKind kind);

/// Type-erased view of a signal, for the builder, introspection, tracing and bindings.
class SignalBase {
 public:
  SignalBase(const SignalBase&) = delete;
  SignalBase& operator=(const SignalBase&) = delete;
  virtual ~SignalBase() = default;

  const std::string& name() const { return name_; }
  const Entity& owner() const { return *owner_; }
  Entity& mutable_owner() const { return *owner_; }
  std::string full_name() const;  ///< "entity.signal"
  SignalKind kind() const { return kind_; }
  bool is_input() const { return kind_ == SignalKind::kInput; }

  virtual std::type_index type() const = 0;
  virtual const char* type_name() const = 0;
  virtual Shape shape() const = 0;

  /// Evaluates the signal at tick t (computing it if not yet done for t.index).
  virtual void Pull(const Tick& t) = 0;
  /// Copies the current value, flattened column-major, into out[0 .. shape().size()).
  virtual void Flatten(double* out) const = 0;
  /// True when every entry of the current value is finite.
  virtual bool IsFinite() const = 0;

  /// Outputs: the signals declared as prerequisites of Calc. Inputs: empty (see source()).
  const std::vector<const SignalBase*>& prerequisites() const { return prerequisites_; }

  /// Where this signal's computation time is charged (its entity's), nullptr when not profiling.
  void set_timing(EntityTiming* timing) { timing_ = timing; }

 protected:
  SignalBase(Entity* owner, std::string name, SignalKind kind)
      : owner_(owner), name_(std::move(name)), kind_(kind) {}
  std::vector<const SignalBase*> prerequisites_;
  EntityTiming* timing_ = nullptr;

 private:
  Entity* owner_;
  std::string name_;
  SignalKind kind_;
};

/// Type-erased input, so the builder can plug and set inputs from names and flat arrays.
class InputSignalBase : public SignalBase {
 public:
  /// The output this input is plugged to, or nullptr when it holds a fixed value or nothing.
  virtual const SignalBase* source() const = 0;
  bool is_plugged() const { return source() != nullptr; }
  /// True when the input holds a fixed value (used when not plugged).
  virtual bool has_fixed_value() const = 0;
  /// True when the input can be evaluated: plugged, or holding a fixed value.
  bool is_set() const { return is_plugged() || has_fixed_value(); }
  /// Inputs declared settable (gains, references) may be changed while the graph runs.
  bool settable() const { return settable_; }

  /// Plugs this input to `output`; throws GraphError on a type or shape mismatch.
  virtual void PlugFrom(SignalBase& output) = 0;
  /// Removes the plug (the input then holds its last fixed value, if any).
  virtual void Unplug() = 0;
  /// Sets a fixed value from a flat column-major array of exactly shape().size() doubles.
  virtual void SetFlat(const double* data, int size) = 0;

 protected:
  InputSignalBase(Entity* owner, std::string name, bool settable)
      : SignalBase(owner, std::move(name), SignalKind::kInput), settable_(settable) {}

 private:
  bool settable_;
};

template <typename T>
class OutputSignal final : public SignalBase {
 public:
  using Calc = std::function<void(const Tick&, T*)>;

  OutputSignal(Entity* owner, std::string name, SignalKind kind, T model, Calc calc,
               std::vector<const SignalBase*> prerequisites)
      : SignalBase(owner, std::move(name), kind),
        value_(std::move(model)),
        shape_(ValueTraits<T>::ShapeOf(value_)),
        calc_(std::move(calc)) {
    prerequisites_ = std::move(prerequisites);
  }

  /// The value at tick t, computed once per tick index (computed outputs) or as held (source
  /// and state outputs).
  const T& Eval(const Tick& t) {
    if (calc_ && t.index > last_index_) {
      ProfileScope scope(timing_);
      calc_(t, &value_);
      last_index_ = t.index;
      ++num_evaluations_;
    }
    return value_;
  }

  /// The last computed or written value, without evaluating.
  const T& value() const { return value_; }
  /// Source and state outputs: written by their entity between ticks.
  T& mutable_value() { return value_; }
  int64_t last_index() const { return last_index_; }
  /// How many times Calc ran (tests check the once-per-tick caching with it).
  int64_t num_evaluations() const { return num_evaluations_; }

  std::type_index type() const override { return typeid(T); }
  const char* type_name() const override { return ValueTraits<T>::kName; }
  /// The declared shape (the model's), not the current value's: another thread may read it
  /// while the loop rewrites the value (a committed state passes through an empty vector).
  Shape shape() const override { return shape_; }
  void Pull(const Tick& t) override { Eval(t); }
  void Flatten(double* out) const override { ValueTraits<T>::Flatten(value_, out); }
  bool IsFinite() const override { return ValueTraits<T>::IsFinite(value_); }

 private:
  T value_;
  Shape shape_;  // of the model: a computation or a write keeps it (the swaps never allocate)
  Calc calc_;
  int64_t last_index_ = -1;
  int64_t num_evaluations_ = 0;
};

template <typename T>
class InputSignal final : public InputSignalBase {
 public:
  /// `model` fixes the type and shape. `fixed` = the model is also the initial fixed value
  /// (an input with a default); otherwise the input must be plugged or set before Build().
  InputSignal(Entity* owner, std::string name, T model, bool fixed, bool settable)
      : InputSignalBase(owner, std::move(name), settable),
        fixed_(std::move(model)),
        has_fixed_(fixed) {}

  const T& Eval(const Tick& t) { return source_ != nullptr ? source_->Eval(t) : fixed_; }

  /// Holds `value` (shape must match the model's); keeps the plug if any (a plug wins).
  void SetValue(const T& value) {
    if (ValueTraits<T>::ShapeOf(value) != ValueTraits<T>::ShapeOf(fixed_)) {
      throw GraphError("input " + full_name() + ": value of shape " + ShapeString(value) +
                       ", expected " + ShapeString(fixed_));
    }
    fixed_ = value;
    has_fixed_ = true;
  }
  void Plug(OutputSignal<T>& output) { source_ = &output; }

  const SignalBase* source() const override { return source_; }
  bool has_fixed_value() const override { return has_fixed_; }
  void PlugFrom(SignalBase& output) override;
  void Unplug() override { source_ = nullptr; }
  void SetFlat(const double* data, int size) override;

  std::type_index type() const override { return typeid(T); }
  const char* type_name() const override { return ValueTraits<T>::kName; }
  Shape shape() const override { return ValueTraits<T>::ShapeOf(fixed_); }
  void Pull(const Tick& t) override {
    if (source_ != nullptr) source_->Eval(t);
  }
  void Flatten(double* out) const override {
    ValueTraits<T>::Flatten(source_ != nullptr ? source_->value() : fixed_, out);
  }
  bool IsFinite() const override {
    return ValueTraits<T>::IsFinite(source_ != nullptr ? source_->value() : fixed_);
  }

 private:
  static std::string ShapeString(const T& v) {
    const Shape s = ValueTraits<T>::ShapeOf(v);
    return std::to_string(s.rows) + "x" + std::to_string(s.cols);
  }
  T fixed_;
  bool has_fixed_;
  OutputSignal<T>* source_ = nullptr;
};

/// Checks that `output` may feed `input` (an output, same type, same shape); throws GraphError
/// naming both signals otherwise.
void CheckPluggable(const SignalBase& output, const SignalBase& input);

template <typename T>
void InputSignal<T>::PlugFrom(SignalBase& output) {
  CheckPluggable(output, *this);
  source_ = static_cast<OutputSignal<T>*>(&output);
}

template <typename T>
void InputSignal<T>::SetFlat(const double* data, int size) {
  const Shape s = shape();
  if (size != s.size()) {
    throw GraphError("input " + full_name() + ": " + std::to_string(size) + " values given, " +
                     std::to_string(s.size()) + " expected (" + std::to_string(s.rows) + "x" +
                     std::to_string(s.cols) + ")");
  }
  ValueTraits<T>::Unflatten(data, &fixed_);
  has_fixed_ = true;
}

}  // namespace marionette::graph
