// GraphEdit + Graph::Apply: a controller replaced between two ticks.
#include <gtest/gtest.h>

#include <atomic>
#include <thread>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"

namespace marionette::graph {
namespace {

struct Fixture {
  // c (1, 1) -> old gain (x2) -> integrator
  std::unique_ptr<Graph> graph;
  VectorIntegrator* integrator = nullptr;
  Fixture() {
    GraphBuilder b;
    auto& c = b.Add<VectorConstant>("c", Eigen::Vector2d(1.0, 1.0));
    auto& gain = b.Add<VectorGain>("controller", 2, 2.0);
    integrator = &b.Add<VectorIntegrator>("integrator", Eigen::Vector2d::Zero());
    b.Connect(c.out_output(), gain.in_input());
    b.Connect(gain.out_output(), integrator->derivative_input());
    graph = b.Build();
  }
};

TEST(GraphEditTest, SwapsAControllerAtATickBoundary) {
  Fixture f;
  Tick t;
  RunTicks(*f.graph, &t, 10);  // integrator = 10 * dt * 2

  auto edit = std::make_unique<GraphEdit>(*f.graph);
  std::weak_ptr<Entity> old_controller;
  for (const auto& e : f.graph->entities()) {
    if (e->name() == "controller") old_controller = e;
  }
  auto& next = edit->Add<VectorGain>("controller_v2", 2, 3.0);
  edit->Connect("c.out", "controller_v2.in");
  edit->Connect(next.out_output(), f.integrator->derivative_input());
  edit->Remove("controller");
  edit->Prepare();
  // Prepared but not applied: the running graph is untouched.
  RunTicks(*f.graph, &t, 10);
  EXPECT_TRUE(f.integrator->state_output().value().isApprox(Eigen::Vector2d(0.04, 0.04)));
  EXPECT_EQ(f.graph->FindEntity("controller_v2"), nullptr);

  ASSERT_TRUE(f.graph->Apply(edit.get()));
  EXPECT_EQ(f.graph->version(), 2);
  EXPECT_NE(f.graph->FindEntity("controller_v2"), nullptr);
  EXPECT_EQ(f.graph->FindEntity("controller"), nullptr);
  EXPECT_FALSE(old_controller.expired()) << "kept alive by the edit until it is destroyed";
  RunTicks(*f.graph, &t, 10);
  EXPECT_TRUE(f.integrator->state_output().value().isApprox(Eigen::Vector2d(0.07, 0.07)));
  edit.reset();  // off the loop thread in the controller
  EXPECT_TRUE(old_controller.expired());
}

// The controller builds the next controller's edit on its LCM thread while the loop ticks: the
// plug checks of that edit read the shapes of live signals, whose values the loop is rewriting.
// A state's value passes through a moved-from (empty) vector while it is committed, so a shape
// read from the value could say 0x1 and refuse a good controller ("shape mismatch: ... 8x1 cannot
// feed ... 8x1", one Panda trial in 20). A signal's shape is what it was declared with.
TEST(GraphEditTest, PlugsToLiveStatesWhileTheLoopCommitsThem) {
  Fixture f;
  std::atomic<bool> done{false};
  std::atomic<int64_t> ticks{0};
  std::thread loop([&] {
    Tick t;
    while (!done.load()) {
      RunTicks(*f.graph, &t, 100);
      ticks += 100;
    }
  });
  int refused = 0;
  while (ticks.load() < 2'000'000) {
    GraphEdit edit(*f.graph);
    auto& reader = edit.Add<VectorGain>("reader", 2, 1.0);
    try {
      edit.Connect(f.integrator->state_output(), reader.in_input());
    } catch (const GraphError&) {
      ++refused;
    }
  }
  done = true;
  loop.join();
  EXPECT_EQ(refused, 0);
}

TEST(GraphEditTest, StaleOrUnpreparedEditsAreNotApplied) {
  Fixture f;
  GraphEdit unprepared(*f.graph);
  unprepared.Add<VectorConstant>("extra", Eigen::Vector2d::Zero());
  EXPECT_FALSE(f.graph->Apply(&unprepared));

  GraphEdit first(*f.graph);
  first.Add<VectorConstant>("a", Eigen::Vector2d::Zero());
  first.Prepare();
  GraphEdit second(*f.graph);
  second.Add<VectorConstant>("b", Eigen::Vector2d::Zero());
  second.Prepare();
  EXPECT_TRUE(f.graph->Apply(&first));
  EXPECT_FALSE(f.graph->Apply(&second)) << "prepared against version 1, graph is at 2";
  EXPECT_EQ(f.graph->FindEntity("b"), nullptr);
}

TEST(GraphEditTest, RefusesRemovingAnEntityThatStillFeedsOthers) {
  Fixture f;
  GraphEdit edit(*f.graph);
  edit.Remove("controller");
  try {
    edit.Prepare();
    FAIL() << "expected GraphError";
  } catch (const GraphError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("integrator.derivative"), std::string::npos) << what;
    EXPECT_NE(what.find("controller"), std::string::npos) << what;
  }
  EXPECT_FALSE(f.graph->Apply(&edit));
}

TEST(GraphEditTest, RefusesCyclesCreatedByReplugging) {
  Fixture f;
  GraphEdit edit(*f.graph);
  edit.Connect("controller.out", "controller.in");  // replaces the plug from c: a cycle
  EXPECT_THROW(edit.Prepare(), GraphError);
  // The live plug is unchanged.
  EXPECT_EQ(f.graph->signal("controller.in").is_input(), true);
  EXPECT_EQ(static_cast<InputSignalBase&>(f.graph->signal("controller.in")).source(),
            &f.graph->signal("c.out"));
}

}  // namespace
}  // namespace marionette::graph
