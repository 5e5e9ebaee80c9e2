// SupervisorSilence: a silence is judged on what the receive path handed over, never on the wall
// clock alone while LCM's reader may lag; a receive path that hands over nothing is a silence.
#include <gtest/gtest.h>

#include "marionette/controller/supervisor_silence.h"

namespace marionette::controller {
namespace {

constexpr int64_t kBeat = 1'000'000'000;  // the last heartbeat's arrival [us]
constexpr double kTimeout = 0.5;

TEST(SupervisorSilence, ALaggingReaderIsNotASilence) {
  // 1.2 s of wall clock since the beat, but the newest message handed over arrived 30 ms after
  // it: the beats that followed are still in the kernel, unread.
  EXPECT_EQ(SupervisorSilence(kBeat, kBeat + 30'000, kBeat + 1'200'000, true, kTimeout), 0.0);
}

TEST(SupervisorSilence, AMessageNewerThanTheDeadlineWithNoBeatBeforeItIs) {
  // The controller's own state came back 510 ms after the last beat: no beat arrived between.
  EXPECT_DOUBLE_EQ(SupervisorSilence(kBeat, kBeat + 510'000, kBeat + 511'000, true, kTimeout),
                   0.51);
  // The same while a flood keeps the thread busy (not idle): the message just handled decides.
  EXPECT_DOUBLE_EQ(SupervisorSilence(kBeat, kBeat + 500'000, kBeat + 900'000, false, kTimeout),
                   0.5);
  EXPECT_EQ(SupervisorSilence(kBeat, kBeat + 499'999, kBeat + 900'000, false, kTimeout), 0.0);
}

TEST(SupervisorSilence, AReceivePathThatHandsOverNothingIsASilenceAfterFourTimeouts) {
  const int64_t stall = static_cast<int64_t>(kReceiveStallFactor * kTimeout * 1e6);
  EXPECT_EQ(SupervisorSilence(kBeat, kBeat + 10'000, kBeat + stall - 1, true, kTimeout), 0.0);
  EXPECT_DOUBLE_EQ(SupervisorSilence(kBeat, kBeat + 10'000, kBeat + stall, true, kTimeout),
                   kReceiveStallFactor * kTimeout);
  // Not while messages wait: they are handed over first, and they say.
  EXPECT_EQ(SupervisorSilence(kBeat, kBeat + 10'000, kBeat + stall, false, kTimeout), 0.0);
}

TEST(SupervisorSilence, ABeatThatArrivedLastIsNoSilence) {
  EXPECT_EQ(SupervisorSilence(kBeat, kBeat, kBeat + 1'000, true, kTimeout), 0.0);
}

}  // namespace
}  // namespace marionette::controller
