// Signals: once-per-tick caching, laziness, fixed values, value traits, states.
#include <gtest/gtest.h>

#include <pinocchio/spatial/explog.hpp>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "test_entities.h"

namespace marionette::graph {
namespace {

using testing::Square;

TEST(SignalTest, SharedOutputIsComputedOncePerTickForManyConsumers) {
  constexpr int kConsumers = 6;
  GraphBuilder b;
  auto& x = b.Add<VectorConstant>("x", Eigen::Vector3d(1.0, -2.0, 0.5));
  auto& square = b.Add<Square>("square", 3);
  auto& sum = b.Add<VectorSum>("sum", 3, kConsumers);
  b.Connect(x.out_output(), square.x());
  for (int i = 0; i < kConsumers; ++i) {
    auto& gain = b.Add<VectorGain>("gain" + std::to_string(i), 3, 0.5 * (i + 1));
    b.Connect(square.y(), gain.in_input());
    b.Connect(gain.out_output(), sum.in(i));
  }
  auto& integrator = b.Add<VectorIntegrator>("integrator", Eigen::Vector3d::Zero());
  b.Connect(sum.out_output(), integrator.derivative_input());
  auto graph = b.Build();

  Tick t;
  RunTicks(*graph, &t, 100);
  EXPECT_EQ(square.y().num_evaluations(), 100);
  EXPECT_EQ(sum.out_output().num_evaluations(), 100);
  // sum = (0.5 + 1 + ... + 3) x^2 = 10.5 x^2 ; the integrator holds 100 dt sum.
  const Eigen::Vector3d expected = 100 * 1e-3 * 10.5 * Eigen::Vector3d(1.0, 4.0, 0.25);
  EXPECT_TRUE(integrator.state_output().value().isApprox(expected, 1e-12));
}

TEST(SignalTest, PullingTwiceInOneTickComputesOnce) {
  Square square("square", 2);
  square.x().SetValue(Eigen::Vector2d(3.0, 4.0));
  Tick t{.index = 5};
  EXPECT_EQ(square.y().Eval(t), Eigen::Vector2d(9.0, 16.0));
  square.x().SetValue(Eigen::Vector2d(1.0, 1.0));
  EXPECT_EQ(square.y().Eval(t), Eigen::Vector2d(9.0, 16.0)) << "cached for tick 5";
  EXPECT_EQ(square.y().num_evaluations(), 1);
  t.index = 4;
  square.y().Eval(t);
  EXPECT_EQ(square.y().num_evaluations(), 1) << "an older tick never recomputes";
  t.index = 6;
  EXPECT_EQ(square.y().Eval(t), Eigen::Vector2d(1.0, 1.0));
  EXPECT_EQ(square.y().num_evaluations(), 2);
}

TEST(SignalTest, OutputsNobodyPullsAreNeverComputed) {
  GraphBuilder b;
  auto& x = b.Add<VectorConstant>("x", Eigen::Vector2d(1.0, 2.0));
  auto& unused = b.Add<Square>("unused", 2);
  auto& used = b.Add<Square>("used", 2);
  auto& integrator = b.Add<VectorIntegrator>("integrator", Eigen::Vector2d::Zero());
  b.Connect(x.out_output(), unused.x());
  b.Connect(x.out_output(), used.x());
  b.Connect(used.y(), integrator.derivative_input());
  auto graph = b.Build();
  Tick t;
  RunTicks(*graph, &t, 10);
  EXPECT_EQ(unused.y().num_evaluations(), 0);
  EXPECT_EQ(used.y().num_evaluations(), 10);
}

TEST(SignalTest, StateHoldsCurrentValueDuringTheTickAndAdvancesAfter) {
  GraphBuilder b;
  auto& v = b.Add<VectorConstant>("v", Eigen::Vector2d(1.0, -1.0));
  auto& integrator = b.Add<VectorIntegrator>("integrator", Eigen::Vector2d(10.0, 0.0));
  auto& observer = b.Add<Square>("observer", 2);  // reads the state within the tick
  auto& sink = b.Add<VectorIntegrator>("sink", Eigen::Vector2d::Zero());
  b.Connect(v.out_output(), integrator.derivative_input());
  b.Connect(integrator.state_output(), observer.x());
  b.Connect(observer.y(), sink.derivative_input());
  auto graph = b.Build();
  Tick t{.index = 0, .time = 0.0, .dt = 0.01};
  graph->Evaluate(t);
  // During tick 0 the observer saw x_0 = (10, 0); after it, x_1 = x_0 + dt v.
  EXPECT_EQ(observer.y().value(), Eigen::Vector2d(100.0, 0.0));
  EXPECT_TRUE(integrator.state_output().value().isApprox(Eigen::Vector2d(10.01, -0.01)));
  ++t;
  RunTicks(*graph, &t, 99);
  EXPECT_TRUE(integrator.state_output().value().isApprox(Eigen::Vector2d(11.0, -1.0), 1e-12));
}

TEST(SignalTest, PollHooksRunBeforeAnythingIsEvaluated) {
  GraphBuilder b;
  auto& counter = b.Add<testing::TickCounter>("counter");
  auto& sum = b.Add<VectorIntegrator>("sum", Eigen::VectorXd::Zero(1));
  b.Connect(counter.out(), sum.derivative_input());
  auto graph = b.Build();
  Tick t{.index = 0, .time = 0.0, .dt = 1.0};
  RunTicks(*graph, &t, 10);
  // The integrator saw 0, 1, ..., 9 during ticks 0..9: the poll ran first in every tick.
  EXPECT_DOUBLE_EQ(sum.state_output().value()[0], 45.0);
}

TEST(SignalTest, FixedValuesCheckTheirShape) {
  Square square("square", 3);
  EXPECT_FALSE(square.x().is_set());
  EXPECT_THROW(square.x().SetValue(Eigen::Vector2d::Zero()), GraphError);
  const double data[3] = {1, 2, 3};
  EXPECT_THROW(square.x().SetFlat(data, 2), GraphError);
  square.x().SetFlat(data, 3);
  EXPECT_TRUE(square.x().is_set());
  EXPECT_EQ(square.x().Eval(Tick{}), Eigen::Vector3d(1, 2, 3));
}

TEST(SignalTest, TypedAccessNamesWhatWasWrong) {
  Square square("square", 3);
  try {
    square.input<double>("x");
    FAIL() << "expected GraphError";
  } catch (const GraphError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("square.x"), std::string::npos) << what;
    EXPECT_NE(what.find("vector"), std::string::npos) << what;
    EXPECT_NE(what.find("double"), std::string::npos) << what;
  }
}

TEST(SignalTest, Se3FlattensToItsHomogeneousMatrix) {
  const pinocchio::SE3 X(pinocchio::exp3(Eigen::Vector3d(0.1, -0.4, 0.3)),
                         Eigen::Vector3d(1.0, 2.0, 3.0));
  double flat[16];
  ValueTraits<pinocchio::SE3>::Flatten(X, flat);
  EXPECT_EQ(flat[12], 1.0);  // column-major: translation is the last column
  EXPECT_EQ(flat[14], 3.0);
  EXPECT_EQ(flat[15], 1.0);
  pinocchio::SE3 Y = pinocchio::SE3::Identity();
  ValueTraits<pinocchio::SE3>::Unflatten(flat, &Y);
  EXPECT_TRUE(Y.isApprox(X, 1e-15));
}

TEST(SignalTest, MatrixFlattensColumnMajor) {
  Eigen::MatrixXd m(2, 3);
  m << 1, 2, 3, 4, 5, 6;
  double flat[6];
  ValueTraits<Eigen::MatrixXd>::Flatten(m, flat);
  EXPECT_EQ(std::vector<double>(flat, flat + 6), (std::vector<double>{1, 4, 2, 5, 3, 6}));
}

}  // namespace
}  // namespace marionette::graph
