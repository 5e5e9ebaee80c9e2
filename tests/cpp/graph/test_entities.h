#pragma once
// Entities used only by the graph tests.
#include <Eigen/Core>

#include "marionette/graph/entity.h"

namespace marionette::graph::testing {

/// y = x .* x, element-wise; counts its evaluations through OutputSignal::num_evaluations.
class Square final : public Entity {
 public:
  Square(std::string name, int n) : Entity(std::move(name)) {
    x_ = &DeclareInput<Eigen::VectorXd>("x", Eigen::VectorXd::Zero(n));
    y_ = &DeclareOutput<Eigen::VectorXd>("y", Eigen::VectorXd::Zero(n), &Square::CalcY, {x_});
  }
  const char* type_name() const override { return "Square"; }
  InputSignal<Eigen::VectorXd>& x() { return *x_; }
  OutputSignal<Eigen::VectorXd>& y() { return *y_; }

 private:
  void CalcY(const Tick& t, Eigen::VectorXd* y) const { *y = x_->Eval(t).cwiseAbs2(); }
  InputSignal<Eigen::VectorXd>* x_{};
  OutputSignal<Eigen::VectorXd>* y_{};
};

/// A scalar output, to test type mismatches.
class ScalarSource final : public Entity {
 public:
  ScalarSource(std::string name, double v) : Entity(std::move(name)) {
    out_ = &DeclareSource<double>("out", v);
  }
  const char* type_name() const override { return "ScalarSource"; }
  OutputSignal<double>& out() { return *out_; }

 private:
  OutputSignal<double>* out_{};
};

/// A source written by its poll hook at the start of each tick: out = tick index.
class TickCounter final : public Entity {
 public:
  explicit TickCounter(std::string name) : Entity(std::move(name)) {
    out_ = &DeclareSource<Eigen::VectorXd>("out", Eigen::VectorXd::Zero(1));
    DeclarePoll("read", &TickCounter::Read);
  }
  const char* type_name() const override { return "TickCounter"; }
  OutputSignal<Eigen::VectorXd>& out() { return *out_; }

 private:
  void Read(const Tick& t) { out_->mutable_value()[0] = static_cast<double>(t.index); }
  OutputSignal<Eigen::VectorXd>* out_{};
};

}  // namespace marionette::graph::testing
