// Tracer: records chosen signals each tick into its ring buffer; CSV dump after the run.
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <sstream>

#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "marionette/graph/tracer.h"

namespace marionette::graph {
namespace {

TEST(TracerTest, KeepsTheLastCapacityTicks) {
  GraphBuilder b;
  auto& v = b.Add<VectorConstant>("v", Eigen::Vector2d(1.0, 2.0));
  auto& x = b.Add<VectorIntegrator>("x", Eigen::Vector2d::Zero());
  b.Connect(v.out_output(), x.derivative_input());
  auto& tracer = b.Add<Tracer>("tracer", 5, std::vector<const SignalBase*>{&x.state_output()});
  auto graph = b.Build();
  Tick t;
  RunTicks(*graph, &t, 12);
  ASSERT_EQ(tracer.size(), 5);
  EXPECT_EQ(tracer.column_names(),
            (std::vector<std::string>{"tick", "time", "x.state[0]", "x.state[1]"}));
  for (int i = 0; i < 5; ++i) {
    const std::vector<double> row = tracer.Row(i);
    const int tick = 7 + i;  // ticks 7..11 kept
    EXPECT_EQ(row[0], tick);
    EXPECT_NEAR(row[1], tick * 1e-3, 1e-12);
    EXPECT_NEAR(row[2], tick * 1e-3 * 1.0, 1e-12);  // the state seen during tick `tick`
    EXPECT_NEAR(row[3], tick * 1e-3 * 2.0, 1e-12);
  }
  EXPECT_THROW(tracer.Row(5), GraphError);
}

TEST(TracerTest, WritesCsv) {
  GraphBuilder b;
  auto& v = b.Add<VectorConstant>("v", Eigen::Vector2d(1.0, 2.0));
  auto& tracer = b.Add<Tracer>("tracer", 10, std::vector<const SignalBase*>{&v.out_output()});
  auto graph = b.Build();
  Tick t;
  RunTicks(*graph, &t, 3);
  const std::string path = ::testing::TempDir() + "/tracer.csv";
  tracer.WriteCsv(path);
  std::ifstream in(path);
  std::stringstream content;
  content << in.rdbuf();
  EXPECT_EQ(content.str(), "tick,time,v.out[0],v.out[1]\n0,0,1,2\n1,0.001,1,2\n2,0.002,1,2\n");
  std::remove(path.c_str());
}

}  // namespace
}  // namespace marionette::graph
