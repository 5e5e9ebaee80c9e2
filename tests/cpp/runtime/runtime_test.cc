// Lock-free exchange between threads and timing statistics.
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <random>
#include <thread>
#include <vector>

#include "marionette/runtime/loop_clock.h"
#include "marionette/runtime/spsc_queue.h"
#include "marionette/runtime/timing_stats.h"
#include "marionette/runtime/triple_buffer.h"

namespace marionette::runtime {
namespace {

TEST(TripleBufferTest, ReaderSeesOnlyCompleteValuesAndTheyIncrease) {
  // Each value is a vector filled with one number: a torn read would mix two numbers.
  TripleBuffer<std::vector<int64_t>> tb(std::vector<int64_t>(64, -1));
  constexpr int64_t kWrites = 200000;
  std::thread writer([&] {
    for (int64_t i = 0; i < kWrites; ++i) {
      std::fill(tb.write_slot().begin(), tb.write_slot().end(), i);
      tb.Publish();
    }
  });
  int64_t last = -1, fetched = 0;
  while (last < kWrites - 1) {
    if (!tb.Fetch()) continue;
    const auto& v = tb.read_slot();
    ASSERT_TRUE(std::all_of(v.begin(), v.end(), [&](int64_t x) { return x == v[0]; }));
    ASSERT_GT(v[0], last) << "values arrive in order, never twice";
    last = v[0];
    ++fetched;
  }
  writer.join();
  EXPECT_EQ(last, kWrites - 1) << "the newest value is always delivered";
  EXPECT_GT(fetched, 0);
  EXPECT_FALSE(tb.Fetch()) << "nothing new after the last value";
}

TEST(SpscQueueTest, DeliversEverythingInOrderAndRefusesWhenFull) {
  SpscQueue<int> q(1000);
  EXPECT_EQ(q.capacity(), 1000u);
  for (int i = 0; i < 1000; ++i) ASSERT_TRUE(q.Push(i));
  EXPECT_FALSE(q.Push(1000));
  int x = -1;
  for (int i = 0; i < 1000; ++i) {
    ASSERT_TRUE(q.Pop(&x));
    ASSERT_EQ(x, i);
  }
  EXPECT_FALSE(q.Pop(&x));

  constexpr int kItems = 300000;
  std::thread producer([&] {
    for (int i = 0; i < kItems;) i += q.Push(i) ? 1 : 0;
  });
  for (int expected = 0; expected < kItems;) {
    if (q.Pop(&x)) {
      ASSERT_EQ(x, expected);
      ++expected;
    }
  }
  producer.join();
}

TEST(TimingWindowTest, PercentilesMatchSortedRanks) {
  std::mt19937 rng(3);
  std::exponential_distribution<double> dist(0.1);
  TimingWindow window(1000);
  std::vector<double> all;
  for (int i = 0; i < 2500; ++i) {
    const double v = dist(rng);
    window.Add(v);
    all.push_back(v);
  }
  std::vector<double> last(all.end() - 1000, all.end());  // only the window is kept
  std::sort(last.begin(), last.end());
  const TimingSummary s = window.Summarise();
  EXPECT_EQ(s.num_samples, 1000);
  EXPECT_EQ(s.p50, last[499]);
  EXPECT_EQ(s.p99, last[989]);
  EXPECT_EQ(s.max, last[999]);
}

TEST(LoopClockTest, UnpacedClockNeverCountsMisses) {
  LoopClock clock(1e-3, /*speed=*/0.0);
  for (int i = 0; i < 1000; ++i) clock.WaitNextTick();
  EXPECT_EQ(clock.ticks(), 1000);
  EXPECT_EQ(clock.deadline_misses(), 0);
}

TEST(LoopClockTest, OverrunsAreCountedAndReanchored) {
  // 1 ms period; a 30 ms stall is 29 periods late (a miss, no re-anchor with backlog 50);
  // a 80 ms stall exceeds the backlog and re-anchors the schedule.
  LoopClock clock(1e-3, 1.0, /*max_backlog=*/50);
  clock.WaitNextTick();
  std::this_thread::sleep_for(std::chrono::milliseconds(30));
  const TickTiming late = clock.WaitNextTick();
  EXPECT_GE(late.lateness_us, 25000.0);
  EXPECT_EQ(clock.deadline_misses(), 1);
  EXPECT_EQ(clock.reanchors(), 0);
  std::this_thread::sleep_for(std::chrono::milliseconds(80));
  clock.WaitNextTick();
  EXPECT_EQ(clock.reanchors(), 1);
}

}  // namespace
}  // namespace marionette::runtime
