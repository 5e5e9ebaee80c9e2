// Per-tick cost of walking: the footstep manager + pattern generator tick while
// walking (1.6 s preview at 1 kHz), its two parts (ZMP window, preview law), the gains'
// computation, and the TALOS reference stack's tick as the peer it runs beside.
#include <benchmark/benchmark.h>

#include <vector>

#include "marionette/graph/graph.h"
#include "marionette/walk/footstep_manager.h"
#include "marionette/walk/pattern_generator.h"
#include "talos_stack.h"

namespace marionette::walk {
namespace {

FootstepPlan LongWalk() {
  FootstepPlan plan;
  plan.num_steps = FootstepPlan::kMaxSteps;
  for (int k = 0; k < plan.num_steps; ++k) {
    Footstep& s = plan.steps[k];
    s.index = k;
    s.is_left = k % 2 == 1;
    s.placement << 0.15 * (k + 1), s.is_left ? 0.085 : -0.085, 0.0, 0.02 * k;
  }
  return plan;
}

struct WalkGraph {
  WalkGraph() {
    graph::GraphBuilder b;
    FootstepManagerOptions options;
    options.start_delay = 0.0;
    steps =
        &b.Add<FootstepManager>("steps", FootPlacement(0, 0.085, 0, 0),
                                FootPlacement(0, -0.085, 0, 0), Eigen::Vector2d::Zero(), options);
    PreviewControlParams params;
    params.com_height = 0.87;
    pg = &b.Add<PatternGenerator>("pg", params, Eigen::Vector3d(0, 0, 0.87));
    b.Connect(steps->zmp_window_output(), pg->zmp_window_input());
    graph = b.Build();
  }
  // One tick with every output a controller reads (CoM, feet, their velocities).
  void Tick() {
    if (steps->num_queued() == 0) steps->Post(plan);  // keep walking (rare: once per 64 steps)
    graph->Evaluate(tick);
    benchmark::DoNotOptimize(pg->com_velocity_output().Eval(tick).data());
    benchmark::DoNotOptimize(steps->left_foot_output().Eval(tick));
    benchmark::DoNotOptimize(steps->right_foot_velocity_output().Eval(tick).data());
    ++tick;
  }
  FootstepPlan plan = LongWalk();
  FootstepManager* steps;
  PatternGenerator* pg;
  std::unique_ptr<graph::Graph> graph;
  graph::Tick tick;
};

void BM_WalkTick(benchmark::State& state) {
  WalkGraph w;
  for (int i = 0; i < 3000; ++i) w.Tick();  // walking
  for (auto _ : state) w.Tick();
  state.counters["preview_samples"] = w.pg->preview_samples();
}
BENCHMARK(BM_WalkTick);

void BM_PreviewLawTwoAxes(benchmark::State& state) {
  PreviewControlParams params;
  params.com_height = 0.87;
  const PreviewGains g = ComputePreviewGains(params);
  Eigen::MatrixXd window = Eigen::MatrixXd::Random(2, g.Gp.size() + 1) * 0.1;
  CartAxis x, y;
  for (auto _ : state) {
    PreviewStep(g, window.data(), 2, &x);
    PreviewStep(g, window.data() + 1, 2, &y);
    benchmark::DoNotOptimize(x.x.data());
    benchmark::DoNotOptimize(y.x.data());
  }
}
BENCHMARK(BM_PreviewLawTwoAxes);

void BM_ZmpWindow(benchmark::State& state) {
  WalkGraph w;
  for (int i = 0; i < 3000; ++i) w.Tick();
  graph::Tick t = w.tick;
  for (auto _ : state) {
    ++t;  // a new tick index: the window is recomputed (the poll is not run: same plan state)
    benchmark::DoNotOptimize(w.steps->zmp_window_output().Eval(t).data());
  }
}
BENCHMARK(BM_ZmpWindow);

void BM_ComputeGains(benchmark::State& state) {
  PreviewControlParams params;
  params.com_height = 0.87;
  for (auto _ : state) benchmark::DoNotOptimize(ComputePreviewGains(params).Gi);
}
BENCHMARK(BM_ComputeGains)->Unit(benchmark::kMicrosecond);

// The peer: the TALOS reference stack's tick (kinematics, 7 tasks, 4-level solver).
void BM_TalosStackTick(benchmark::State& state) {
  sot::testing::TalosStack s = sot::testing::BuildTalosStack();
  graph::Tick tick;
  for (int i = 0; i < 100; ++i, ++tick) s.graph->Evaluate(tick);
  for (auto _ : state) {
    s.graph->Evaluate(tick);
    ++tick;
  }
}
BENCHMARK(BM_TalosStackTick);

}  // namespace
}  // namespace marionette::walk

BENCHMARK_MAIN();
