// After warm-up, Graph::Evaluate and Graph::Apply allocate nothing and take no lock
// (STYLE.md rule 4; counted by interposing malloc and pthread_mutex_lock).
#include <gtest/gtest.h>

#include <mutex>

#include "allocation_counter.h"
#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "marionette/graph/tracer.h"

namespace marionette::graph {
namespace {

using marionette::testing::ScopedAllocationCounter;

// A controller-sized graph: chains of gains and products feeding integrators, and a tracer.
std::unique_ptr<Graph> MakeGraph(int chains, VectorIntegrator** last) {
  GraphBuilder b;
  auto& q0 = b.Add<VectorConstant>("q0", Eigen::VectorXd::Ones(38));
  std::vector<const SignalBase*> traced;
  for (int c = 0; c < chains; ++c) {
    const std::string id = std::to_string(c);
    auto& jacobian = b.Add<MatrixVectorProduct>("jacobian" + id, 6, 38);
    jacobian.matrix_input().SetValue(Eigen::MatrixXd::Random(6, 38));
    auto& gain = b.Add<VectorGain>("gain" + id, 6, -1.0);
    auto& sum = b.Add<VectorSum>("sum" + id, 6, 2);
    auto& x = b.Add<VectorIntegrator>("x" + id, Eigen::VectorXd::Zero(6));
    b.Connect(q0.out_output(), jacobian.vector_input());
    b.Connect(jacobian.out_output(), sum.in(0));
    b.Connect(x.state_output(), gain.in_input());
    b.Connect(gain.out_output(), sum.in(1));
    b.Connect(sum.out_output(), x.derivative_input());
    traced.push_back(&x.state_output());
    *last = &x;
  }
  b.Add<Tracer>("tracer", 1000, traced);
  return b.Build();
}

TEST(GraphRealtimeTest, CounterSeesAllocationsAndLocks) {
  ScopedAllocationCounter counter;
  std::vector<double> v(100);
  std::mutex m;
  { std::lock_guard<std::mutex> lock(m); }
  EXPECT_GE(counter.allocations(), 1);
  EXPECT_GE(counter.locks(), 1);
}

TEST(GraphRealtimeTest, EvaluateAllocatesNothingAfterWarmUp) {
  VectorIntegrator* last = nullptr;
  auto graph = MakeGraph(7, &last);
  Tick t;
  RunTicks(*graph, &t, 100);  // warm-up
  ScopedAllocationCounter counter;
  RunTicks(*graph, &t, 10000);
  EXPECT_EQ(counter.allocations(), 0);
  EXPECT_EQ(counter.locks(), 0);
  EXPECT_TRUE(last->state_output().value().allFinite());
}

TEST(GraphRealtimeTest, ProfilingAllocatesNothingEither) {
  VectorIntegrator* last = nullptr;
  auto graph = MakeGraph(7, &last);
  graph->SetProfiling(true);
  for (const auto& e : graph->entities()) e->set_time_budget_us(1.0);
  std::vector<const Entity*> over;
  over.reserve(64);
  Tick t;
  RunTicks(*graph, &t, 100);
  ScopedAllocationCounter counter;
  for (int i = 0; i < 10000; ++i, ++t) {
    graph->Evaluate(t);
    graph->LastOverruns(&over);
  }
  EXPECT_EQ(counter.allocations(), 0);
  EXPECT_EQ(counter.locks(), 0);
  EXPECT_EQ(last->timing().window.num_samples, 10100);
}

TEST(GraphRealtimeTest, ApplyingAPreparedEditAllocatesNothing) {
  VectorIntegrator* last = nullptr;
  auto graph = MakeGraph(3, &last);
  Tick t;
  RunTicks(*graph, &t, 10);
  auto edit = std::make_unique<GraphEdit>(*graph);
  auto& gain = edit->Add<VectorGain>("gain2_v2", 6, -2.0);
  edit->Connect("x2.state", "gain2_v2.in");
  edit->Connect("gain2_v2.out", "sum2.in1");
  edit->Remove("gain2");
  edit->Prepare();
  {
    ScopedAllocationCounter counter;
    ASSERT_TRUE(graph->Apply(edit.get()));
    RunTicks(*graph, &t, 100);
    EXPECT_EQ(counter.allocations(), 0);
    EXPECT_EQ(counter.locks(), 0);
  }
  EXPECT_EQ(gain.out_output().num_evaluations(), 100);
}

}  // namespace
}  // namespace marionette::graph
