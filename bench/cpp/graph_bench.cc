// Overhead of the dynamic graph on a graph the size of a TALOS controller (30 entities, 150
// signals): time per tick, per signal evaluation, and against the same arithmetic written
// directly (no graph) so the framework's own cost is visible.
#include <benchmark/benchmark.h>

#include <Eigen/Core>
#include <vector>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"

namespace marionette::graph {
namespace {

constexpr int kEntities = 30;  // 30 relays x 5 signals = 150 signals (plus 2 for the sink)
constexpr int kSize = 6;

/// out0 = gain * in0, out1 = in0 + in1: five signals, two computed outputs.
class Relay final : public Entity {
 public:
  Relay(std::string name, int n) : Entity(std::move(name)) {
    in0_ = &DeclareInput<Eigen::VectorXd>("in0", Eigen::VectorXd::Zero(n));
    in1_ = &DeclareInput<Eigen::VectorXd>("in1", Eigen::VectorXd::Zero(n));
    gain_ = &DeclareParameter<double>("gain", 0.5);
    out0_ = &DeclareOutput<Eigen::VectorXd>("out0", Eigen::VectorXd::Zero(n), &Relay::CalcOut0,
                                            {in0_, gain_});
    out1_ = &DeclareOutput<Eigen::VectorXd>("out1", Eigen::VectorXd::Zero(n), &Relay::CalcOut1,
                                            {in0_, in1_});
  }
  const char* type_name() const override { return "Relay"; }
  InputSignal<Eigen::VectorXd>* in0_{};
  InputSignal<Eigen::VectorXd>* in1_{};
  InputSignal<double>* gain_{};
  OutputSignal<Eigen::VectorXd>* out0_{};
  OutputSignal<Eigen::VectorXd>* out1_{};

 private:
  void CalcOut0(const Tick& t, Eigen::VectorXd* out) const {
    *out = gain_->Eval(t) * in0_->Eval(t);
  }
  void CalcOut1(const Tick& t, Eigen::VectorXd* out) const { *out = in0_->Eval(t) + in1_->Eval(t); }
};

// Relay i reads relays i-1 and i-2 (a DAG where outputs are shared by two consumers), the last
// one feeds an integrator whose state loops back to the first relays.
std::unique_ptr<Graph> MakeControllerSizedGraph(std::vector<Relay*>* relays) {
  GraphBuilder b;
  auto& x = b.Add<VectorIntegrator>("x", Eigen::VectorXd::Ones(kSize));
  for (int i = 0; i < kEntities; ++i)
    relays->push_back(&b.Add<Relay>("relay" + std::to_string(i), kSize));
  auto& r = *relays;
  b.Connect(x.state_output(), *r[0]->in0_);
  b.Connect(x.state_output(), *r[0]->in1_);
  b.Connect(*r[0]->out0_, *r[1]->in0_);
  b.Connect(x.state_output(), *r[1]->in1_);
  for (int i = 2; i < kEntities; ++i) {
    b.Connect(*r[i - 1]->out0_, *r[i]->in0_);
    b.Connect(*r[i - 2]->out1_, *r[i]->in1_);
  }
  auto& damping = b.Add<VectorGain>("damping", kSize, -1e-3);
  b.Connect(*r[kEntities - 1]->out1_, damping.in_input());
  b.Connect(damping.out_output(), x.derivative_input());
  return b.Build();
}

void BM_TickControllerSizedGraph(benchmark::State& state) {
  std::vector<Relay*> relays;
  auto graph = MakeControllerSizedGraph(&relays);
  Tick t;
  for (int i = 0; i < 100; ++i, ++t) graph->Evaluate(t);
  int64_t computed_before = 0;
  for (Relay* r : relays)
    computed_before += r->out0_->num_evaluations() + r->out1_->num_evaluations();
  for (auto _ : state) {
    graph->Evaluate(t);
    ++t;
  }
  int64_t computed = -computed_before;
  for (Relay* r : relays) computed += r->out0_->num_evaluations() + r->out1_->num_evaluations();
  state.counters["signals"] = graph->num_signals();
  state.counters["entities"] = static_cast<double>(graph->entities().size());
  state.counters["outputs_per_tick"] = static_cast<double>(computed) / state.iterations();
}
BENCHMARK(BM_TickControllerSizedGraph);

// The same arithmetic without the graph: what the graph's bookkeeping is compared with.
void BM_TickSameArithmeticWithoutGraph(benchmark::State& state) {
  std::vector<Eigen::VectorXd> out0(kEntities, Eigen::VectorXd::Zero(kSize));
  std::vector<Eigen::VectorXd> out1(kEntities, Eigen::VectorXd::Zero(kSize));
  Eigen::VectorXd x = Eigen::VectorXd::Ones(kSize), xdot(kSize);
  const double gain = 0.5, dt = 1e-3;
  for (auto _ : state) {
    out0[0] = gain * x;
    out1[0] = x + x;
    out0[1] = gain * out0[0];
    out1[1] = out0[0] + x;
    for (int i = 2; i < kEntities; ++i) {
      out0[i] = gain * out0[i - 1];
      out1[i] = out0[i - 1] + out1[i - 2];
    }
    xdot = -1e-3 * out1[kEntities - 1];
    x += dt * xdot;
    benchmark::DoNotOptimize(x.data());
  }
}
BENCHMARK(BM_TickSameArithmeticWithoutGraph);

void BM_EvalCachedOutput(benchmark::State& state) {
  VectorGain gain("g", kSize, 2.0);
  gain.in_input().SetValue(Eigen::VectorXd::Ones(kSize));
  const Tick t{.index = 1};
  gain.out_output().Eval(t);
  for (auto _ : state) benchmark::DoNotOptimize(gain.out_output().Eval(t).data());
}
BENCHMARK(BM_EvalCachedOutput);

void BM_EvalRecomputedOutput(benchmark::State& state) {
  VectorGain gain("g", kSize, 2.0);
  gain.in_input().SetValue(Eigen::VectorXd::Ones(kSize));
  Tick t;
  for (auto _ : state) {
    ++t.index;
    benchmark::DoNotOptimize(gain.out_output().Eval(t).data());
  }
}
BENCHMARK(BM_EvalRecomputedOutput);

}  // namespace
}  // namespace marionette::graph

BENCHMARK_MAIN();
