// Per-entity profiling: self time charged to the entity that computed (nested pulls excluded),
// histogram quantiles, budgets and overruns, and new entities of an edit profiled too.
#include <gtest/gtest.h>

#include <chrono>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "test_entities.h"

namespace marionette::graph {
namespace {

/// out = in, after spinning for `spin_us` (a deterministic lower bound on its compute time).
class Spin final : public Entity {
 public:
  Spin(std::string name, double spin_us) : Entity(std::move(name)), spin_us_(spin_us) {
    in_ = &DeclareInput<Eigen::VectorXd>("in", Eigen::VectorXd::Zero(1));
    out_ = &DeclareOutput<Eigen::VectorXd>("out", Eigen::VectorXd::Zero(1), &Spin::CalcOut, {in_});
  }
  const char* type_name() const override { return "Spin"; }
  InputSignal<Eigen::VectorXd>& in() { return *in_; }
  OutputSignal<Eigen::VectorXd>& out() { return *out_; }

 private:
  void CalcOut(const Tick& t, Eigen::VectorXd* out) const {
    const auto until =
        std::chrono::steady_clock::now() + std::chrono::duration<double, std::micro>(spin_us_);
    while (std::chrono::steady_clock::now() < until) {
    }
    *out = in_->Eval(t);
  }
  double spin_us_;
  InputSignal<Eigen::VectorXd>* in_{};
  OutputSignal<Eigen::VectorXd>* out_{};
};

TEST(DurationHistogramTest, QuantilesBracketTheSamples) {
  DurationHistogram h;
  for (int i = 1; i <= 1000; ++i) h.Add(1000.0 * i);  // 1 us .. 1 ms
  EXPECT_EQ(h.num_samples, 1000);
  EXPECT_EQ(h.max_ns, 1e6);
  // Within one bin (19 %) above the exact quantile.
  EXPECT_GE(h.Quantile(0.5), 500e3);
  EXPECT_LE(h.Quantile(0.5), 500e3 * 1.19);
  EXPECT_GE(h.Quantile(0.99), 990e3);
  EXPECT_LE(h.Quantile(0.99), 1e6);
}

TEST(ProfilingTest, SelfTimeGoesToTheEntityThatComputed) {
  GraphBuilder b;
  auto& source = b.Add<VectorConstant>("source", Eigen::VectorXd::Ones(1));
  auto& slow = b.Add<Spin>("slow", 300.0);
  auto& consumer = b.Add<VectorIntegrator>("consumer", Eigen::VectorXd::Zero(1));
  b.Connect(source.out_output(), slow.in());
  b.Connect(slow.out(), consumer.derivative_input());
  auto graph = b.Build();
  slow.set_time_budget_us(100.0);
  graph->SetProfiling(true);
  Tick t;
  RunTicks(*graph, &t, 50);
  const EntityTiming& s = slow.timing();
  const EntityTiming& c = consumer.timing();
  EXPECT_EQ(s.window.num_samples, 50);
  EXPECT_GE(s.window.Quantile(0.5), 300e3) << "at least the spin";
  // The consumer pulled the slow output inside its own update: that time is not its own.
  EXPECT_LT(c.window.Quantile(0.5), s.window.Quantile(0.5) / 4);
  EXPECT_EQ(s.overruns, 50);
  EXPECT_EQ(s.consecutive_overruns, 50);
  EXPECT_EQ(c.overruns, 0) << "no budget, no overrun";
  std::vector<const Entity*> over;
  over.reserve(8);
  EXPECT_EQ(graph->LastOverruns(&over), 1);
  EXPECT_EQ(over[0], &slow);
}

TEST(ProfilingTest, EntitiesOfAnEditAreProfiledAndOffMeansNothingIsCounted) {
  GraphBuilder b;
  auto& source = b.Add<VectorConstant>("source", Eigen::VectorXd::Ones(1));
  auto& x = b.Add<VectorIntegrator>("x", Eigen::VectorXd::Zero(1));
  b.Connect(source.out_output(), x.derivative_input());
  auto graph = b.Build();
  Tick t;
  RunTicks(*graph, &t, 10);
  EXPECT_EQ(x.timing().window.num_samples, 0) << "profiling is off by default";
  graph->SetProfiling(true);
  GraphEdit edit(*graph);
  auto& spin = edit.Add<Spin>("spin", 50.0);
  edit.Connect("source.out", "spin.in");
  edit.Connect(spin.out(), x.derivative_input());
  edit.Prepare();
  ASSERT_TRUE(graph->Apply(&edit));
  RunTicks(*graph, &t, 10);
  EXPECT_EQ(spin.timing().window.num_samples, 10);
  EXPECT_GE(spin.timing().window.Quantile(0.5), 50e3);
}

}  // namespace
}  // namespace marionette::graph
