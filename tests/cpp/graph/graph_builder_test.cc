// GraphBuilder: every kind of miswiring is refused with a message naming what is wrong.
#include <gtest/gtest.h>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "test_entities.h"

namespace marionette::graph {
namespace {

using testing::ScalarSource;
using testing::Square;

// Runs `f`, expects a GraphError whose message contains every string of `needles`.
template <typename F>
void ExpectGraphError(F f, std::initializer_list<const char*> needles) {
  try {
    f();
  } catch (const GraphError& e) {
    const std::string what = e.what();
    for (const char* n : needles) EXPECT_NE(what.find(n), std::string::npos) << what;
    return;
  }
  ADD_FAILURE() << "expected a GraphError";
}

TEST(GraphBuilderTest, RefusesTypeMismatch) {
  GraphBuilder b;
  auto& s = b.Add<ScalarSource>("scalar", 1.0);
  auto& sq = b.Add<Square>("square", 1);
  ExpectGraphError([&] { b.Connect(s.out(), sq.x()); },
                   {"type mismatch", "scalar.out", "square.x", "double", "vector"});
}

TEST(GraphBuilderTest, RefusesShapeMismatch) {
  GraphBuilder b;
  auto& c = b.Add<VectorConstant>("c", Eigen::Vector3d::Zero());
  auto& sq = b.Add<Square>("square", 4);
  ExpectGraphError([&] { b.Connect(c.out_output(), sq.x()); },
                   {"shape mismatch", "c.out", "3x1", "square.x", "4x1"});
}

TEST(GraphBuilderTest, RefusesDanglingInputs) {
  GraphBuilder b;
  b.Add<Square>("square", 2);
  b.Add<VectorSum>("sum", 2, 2);
  ExpectGraphError([&] { b.Build(); },
                   {"square.x", "sum.in0", "sum.in1", "neither plugged nor set"});
}

TEST(GraphBuilderTest, RefusesAlgebraicCycles) {
  GraphBuilder b;
  auto& g1 = b.Add<VectorGain>("g1", 2, 1.0);
  auto& g2 = b.Add<VectorGain>("g2", 2, 1.0);
  b.Connect(g1.out_output(), g2.in_input());
  b.Connect(g2.out_output(), g1.in_input());
  ExpectGraphError([&] { b.Build(); }, {"cycle", "g1.out", "g2.in", "g2.out", "g1.in"});
}

TEST(GraphBuilderTest, AcceptsLoopsThroughAState) {
  // x' = -x closes the loop through the integrator's state: a valid (delayed) feedback.
  GraphBuilder b;
  auto& integrator = b.Add<VectorIntegrator>("x", Eigen::Vector2d(1.0, 2.0));
  auto& gain = b.Add<VectorGain>("minus", 2, -1.0);
  b.Connect(integrator.state_output(), gain.in_input());
  b.Connect(gain.out_output(), integrator.derivative_input());
  auto graph = b.Build();
  Tick t{.index = 0, .time = 0.0, .dt = 1e-3};
  RunTicks(*graph, &t, 1000);
  // Explicit Euler of x' = -x over 1 s: (1 - dt)^1000 x0.
  const double decay = std::pow(1.0 - 1e-3, 1000);
  EXPECT_TRUE(integrator.state_output().value().isApprox(decay * Eigen::Vector2d(1.0, 2.0), 1e-12));
}

TEST(GraphBuilderTest, RefusesDuplicateNamesAndDoublePlugs) {
  GraphBuilder b;
  auto& c = b.Add<VectorConstant>("c", Eigen::Vector2d::Zero());
  ExpectGraphError([&] { b.Add<VectorConstant>("c", Eigen::Vector2d::Zero()); }, {"'c'"});
  auto& sq = b.Add<Square>("square", 2);
  b.Connect(c.out_output(), sq.x());
  auto& c2 = b.Add<VectorConstant>("c2", Eigen::Vector2d::Zero());
  ExpectGraphError([&] { b.Connect(c2.out_output(), sq.x()); },
                   {"square.x", "already plugged", "c.out"});
}

TEST(GraphBuilderTest, RefusesWrongDirectionsAndStrangers) {
  GraphBuilder b;
  auto& c = b.Add<VectorConstant>("c", Eigen::Vector2d::Zero());
  auto& sq = b.Add<Square>("square", 2);
  ExpectGraphError([&] { b.Connect(sq.x(), c.value_input()); }, {"must be an output"});
  ExpectGraphError([&] { b.Connect(c.out_output(), sq.y()); }, {"must be an input"});
  Square stranger("stranger", 2);
  ExpectGraphError([&] { b.Connect(c.out_output(), stranger.x()); }, {"stranger", "not added"});
}

TEST(GraphBuilderTest, ConnectsByNameAndReportsUnknownNames) {
  GraphBuilder b;
  b.Add<VectorConstant>("c", Eigen::Vector2d(1.0, 2.0));
  b.Add<Square>("square", 2);
  b.Connect("c.out", "square.x");
  ExpectGraphError([&] { b.Connect("c.nope", "square.x"); }, {"'c'", "no signal 'nope'", "out"});
  ExpectGraphError([&] { b.Connect("nobody.out", "square.x"); }, {"nobody"});
  ExpectGraphError([&] { b.Connect("c", "square.x"); }, {"entity.signal"});
  auto graph = b.Build();
  EXPECT_EQ(graph->signal("square.x").shape().rows, 2);
  EXPECT_EQ(graph->FindSignal("square.nope"), nullptr);
  EXPECT_EQ(graph->num_signals(), 4);
}

TEST(GraphBuilderTest, ExportsDotWithPortsAndPlugs) {
  GraphBuilder b;
  auto& c = b.Add<VectorConstant>("c", Eigen::Vector2d(1.0, 2.0));
  auto& sq = b.Add<Square>("square", 2);
  b.Connect(c.out_output(), sq.x());
  auto graph = b.Build();
  const std::string dot = graph->ToDot();
  EXPECT_NE(dot.find("digraph"), std::string::npos);
  EXPECT_NE(dot.find("\"c\":\"out\":e -> \"square\":\"x\":w"), std::string::npos) << dot;
  EXPECT_NE(dot.find("Square"), std::string::npos);
  EXPECT_NE(dot.find("value\\ =\\ 1\\ 2"), std::string::npos) << dot;
}

}  // namespace
}  // namespace marionette::graph
