// ReferenceStream: streamed chunks sampled at the tick, replaced futures, age and end, slerp,
// refused chunks, and no allocation in the loop while another thread pushes.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <thread>

#include "allocation_counter.h"
#include "marionette/controller/reference_stream.h"
#include "marionette/graph/graph.h"

namespace marionette::controller {
namespace {

ReferenceChunk Ramp(int64_t start_us, int n, double v0, double slope_per_sample,
                    bool last = false) {
  ReferenceChunk c;
  c.start_us = start_us;
  c.dt_us = 1000;
  c.num_samples = n;
  for (int i = 0; i < n; ++i) {
    c.values.push_back(v0 + slope_per_sample * i);
    c.derivatives.push_back(slope_per_sample * 1000.0);
  }
  c.last = last;
  return c;
}

graph::Tick At(int64_t us) { return graph::Tick{us / 1000, us * 1e-6, 1e-3}; }

TEST(ReferenceStreamTest, SamplesInterpolatesAndHolds) {
  ReferenceStream s("s", ReferenceStream::Kind::kVector, Eigen::VectorXd::Constant(1, 7.0), 1);
  // Before any chunk: the initial value, not stale.
  EXPECT_EQ(s.value_output().Eval(At(0))[0], 7.0);
  EXPECT_EQ(s.age_output().Eval(At(0)), 0.0);
  ASSERT_EQ(s.ValidateChunk(Ramp(10000, 100, 0.0, 0.01)), "");
  ASSERT_TRUE(s.Push(Ramp(10000, 100, 0.0, 0.01)));
  graph::GraphBuilder b;  // the poll hook runs through a graph
  auto graph_entity = std::shared_ptr<ReferenceStream>(&s, [](ReferenceStream*) {});
  b.AddShared(graph_entity);
  auto g = b.Build();
  // Before the first sample (10 ms): the first sample is held.
  graph::Tick t = At(3000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], 0.0, 1e-12);
  t = At(20000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], 0.10, 1e-12);
  EXPECT_NEAR(s.derivative_output().Eval(t)[0], 10.0, 1e-12);
  // Between two samples (t = 20.5 ms, a later tick index): linear interpolation.
  const graph::Tick half{21, 0.0205, 1e-3};
  EXPECT_NEAR(s.value_output().Eval(half)[0], 0.105, 1e-12);
  // After the last (109 ms): held, stale by the time past it, no feed-forward.
  t = At(150000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], 0.99, 1e-12);
  EXPECT_NEAR(s.age_output().Eval(t), 0.041, 1e-9);
  EXPECT_EQ(s.derivative_output().Eval(t)[0], 0.0);
  EXPECT_FALSE(s.ended_output().Eval(t));
}

TEST(ReferenceStreamTest, ALaterChunkReplacesTheFutureAndMayEndTheReference) {
  ReferenceStream s("s", ReferenceStream::Kind::kVector, Eigen::VectorXd::Zero(1), 1);
  graph::GraphBuilder b;
  b.AddShared(std::shared_ptr<ReferenceStream>(&s, [](ReferenceStream*) {}));
  auto g = b.Build();
  s.Push(Ramp(0, 1000, 0.0, 1.0));            // 0 .. 999 over 1 s
  s.Push(Ramp(500000, 10, -5.0, 0.0, true));  // from 0.5 s: -5 for 10 ms, the end
  graph::Tick t = At(400000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], 400.0, 1e-12);
  t = At(700000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], -5.0, 1e-12) << "the old samples after 0.5 s are gone";
  EXPECT_TRUE(s.ended_output().Eval(t));
}

// An unpaced loop waits while a stream is starved: no sample yet or all of them behind the tick,
// the reference not ended, nothing queued. Inside the samples, with a chunk queued and after the
// last chunk it is not.
TEST(ReferenceStreamTest, StarvedWithoutSamplesCoveringTheTickNorAChunkQueuedBeforeTheEnd) {
  ReferenceStream s("s", ReferenceStream::Kind::kVector, Eigen::VectorXd::Zero(1), 1);
  graph::GraphBuilder b;
  b.AddShared(std::shared_ptr<ReferenceStream>(&s, [](ReferenceStream*) {}));
  auto g = b.Build();
  EXPECT_TRUE(s.Starved(0)) << "no sample yet";
  ASSERT_TRUE(s.Push(Ramp(0, 100, 0.0, 1.0)));  // samples at 0 .. 99 ms
  EXPECT_FALSE(s.Starved(150000)) << "the chunk waits in the queue";
  g->Evaluate(At(0));
  EXPECT_FALSE(s.Starved(99000)) << "the last sample";
  EXPECT_TRUE(s.Starved(100000));
  EXPECT_TRUE(s.Starved(150000));
  ASSERT_TRUE(s.Push(Ramp(100000, 100, 100.0, 1.0)));
  EXPECT_FALSE(s.Starved(150000));
  g->Evaluate(At(1000));
  EXPECT_FALSE(s.Starved(199000));
  EXPECT_TRUE(s.Starved(200000));
  ASSERT_TRUE(s.Push(Ramp(200000, 10, 200.0, 1.0, /*last=*/true)));
  g->Evaluate(At(2000));
  EXPECT_FALSE(s.Starved(500000)) << "an ended reference holds its last sample";
}

// A plank-flip trial (seed 105) lost the last chunks of a 4 s burst in LCM's receive queue; the
// next chunk, 1 s further on, then became the stream's only samples and the robot jumped 4 s
// ahead along its plan. A numbered chunk whose predecessor never came is refused: the stream
// holds its last sample and grows stale, so the watchdog holds the robot instead.
TEST(ReferenceStreamTest, AChunkAfterALostOneIsRefusedAndTheStreamHoldsItsLastSample) {
  ReferenceStream s("s", ReferenceStream::Kind::kVector, Eigen::VectorXd::Zero(1), 1);
  graph::GraphBuilder b;
  b.AddShared(std::shared_ptr<ReferenceStream>(&s, [](ReferenceStream*) {}));
  auto g = b.Build();
  const auto numbered = [](ReferenceChunk c, int sequence) {
    c.sequence = sequence;
    return c;
  };
  const ReferenceChunk first = numbered(Ramp(0, 200, 0.0, 1.0), 0);          // samples 0 .. 199
  const ReferenceChunk second = numbered(Ramp(200000, 200, 200.0, 1.0), 1);  // 200 .. 399
  const ReferenceChunk after_a_loss = numbered(Ramp(600000, 200, 600.0, 1.0), 3);  // chunk 2 lost
  EXPECT_NE(
      s.ValidateChunk(second).find("chunk 1 of a reference whose chunk 0 never came (none taken)"),
      std::string::npos)
      << "a reference cannot start with its second chunk";
  ASSERT_EQ(s.ValidateChunk(first), "");
  ASSERT_TRUE(s.Push(first));
  ASSERT_EQ(s.ValidateChunk(second), "");
  ASSERT_TRUE(s.Push(second));
  const std::string problem = s.ValidateChunk(after_a_loss);
  EXPECT_NE(problem.find("chunk 3 of a reference whose chunk 2 never came (last taken 1)"),
            std::string::npos)
      << problem;
  // The lost chunk itself, a chunk standing alone (a servo's, or a new reference after a pause,
  // however far on) and a negative number.
  EXPECT_EQ(s.ValidateChunk(numbered(Ramp(400000, 200, 400.0, 1.0), 2)), "");
  EXPECT_EQ(s.ValidateChunk(numbered(Ramp(3000000, 10, 0.0, 0.0), 0)), "");
  EXPECT_NE(s.ValidateChunk(numbered(Ramp(400000, 10, 0.0, 0.0), -1)).find("negative sequence"),
            std::string::npos);
  // What a refused chunk leaves: the stream ends at sample 399, held and aging past it.
  graph::Tick t = At(300000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], 300.0, 1e-12);
  t = At(650000);
  g->Evaluate(t);
  EXPECT_NEAR(s.value_output().Eval(t)[0], 399.0, 1e-12) << "no jump to the chunk after the loss";
  EXPECT_NEAR(s.age_output().Eval(t), 0.251, 1e-9);
}

TEST(ReferenceStreamTest, Se3StreamsSlerpAndCheckQuaternions) {
  ReferenceStream s("s", ReferenceStream::Kind::kSe3,
                    (Eigen::VectorXd(7) << 0, 0, 0, 1, 0, 0, 0).finished(), 6);
  graph::GraphBuilder b;
  b.AddShared(std::shared_ptr<ReferenceStream>(&s, [](ReferenceStream*) {}));
  auto g = b.Build();
  ReferenceChunk c;
  c.start_us = 0;
  c.dt_us = 1000;
  c.num_samples = 2;
  const Eigen::Quaterniond q1(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()));
  c.values = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, q1.w(), q1.x(), q1.y(), q1.z()};
  c.derivatives.assign(12, 0.0);
  ASSERT_EQ(s.ValidateChunk(c), "");
  s.Push(c);
  const graph::Tick t{0, 0.0005, 1e-3};
  g->Evaluate(t);
  const pinocchio::SE3& X = s.pose_output()->Eval(t);
  EXPECT_NEAR(X.translation().x(), 0.5, 1e-12);
  EXPECT_NEAR(Eigen::AngleAxisd(X.rotation()).angle(), 0.2, 1e-9);
  ReferenceChunk bad = c;
  bad.values[3] = 2.0;
  EXPECT_NE(s.ValidateChunk(bad).find("quaternion"), std::string::npos);
  bad = c;
  bad.values[1] = std::nan("");
  EXPECT_NE(s.ValidateChunk(bad).find("non-finite"), std::string::npos);
  bad = c;
  bad.values.pop_back();
  EXPECT_NE(s.ValidateChunk(bad).find("expected 2 x 7"), std::string::npos);
}

TEST(ReferenceStreamTest, LoopAllocatesNothingWhileAnotherThreadPushes) {
  ReferenceStream s("s", ReferenceStream::Kind::kVector, Eigen::VectorXd::Zero(3), 3, 5000, 100, 8);
  graph::GraphBuilder b;
  b.AddShared(std::shared_ptr<ReferenceStream>(&s, [](ReferenceStream*) {}));
  auto g = b.Build();
  ReferenceChunk chunk;
  chunk.dt_us = 1000;
  chunk.num_samples = 100;
  chunk.values.assign(300, 1.0);
  chunk.derivatives.assign(300, 0.0);
  for (int i = 0; i < 8; ++i) s.Push(chunk);  // warm the queue slots up
  graph::Tick t;
  for (int i = 0; i < 20; ++i, ++t) {
    g->Evaluate(t);
    s.value_output().Eval(t);
  }
  std::atomic<bool> done{false};
  std::thread producer([&] {
    for (int64_t k = 0; !done; ++k) {
      chunk.start_us = k * 50000;
      s.Push(chunk);
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  });
  {
    marionette::testing::ScopedAllocationCounter counter;
    for (int i = 0; i < 5000; ++i, ++t) {
      g->Evaluate(t);
      s.value_output().Eval(t);
      s.age_output().Eval(t);
    }
    EXPECT_EQ(counter.allocations(), 0);
    EXPECT_EQ(counter.locks(), 0);
  }
  done = true;
  producer.join();
}

}  // namespace
}  // namespace marionette::controller
