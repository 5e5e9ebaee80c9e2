// What marionette-sim's servos track each cycle (sim_driver/command_gate.h), on a 2-joint robot
// with a 1 ms period and a 10 ms watchdog.
#include "marionette/sim_driver/command_gate.h"

#include <gtest/gtest.h>

#include "allocation_counter.h"

namespace marionette::sim_driver {
namespace {

constexpr int64_t kPeriodUs = 1000;
constexpr int64_t kTimeoutUs = 10000;

controller::JointCommand Answer(int64_t sequence, double q, int8_t mode = 0) {
  controller::JointCommand c;
  c.sequence = sequence;
  c.utime = sequence * kPeriodUs;
  c.mode = mode;
  c.q = Eigen::Vector2d(q, -q);
  c.v = Eigen::Vector2d(0.5, -0.5);
  return c;
}

class CommandGateTest : public ::testing::Test {
 protected:
  CommandGate gate{2, 2, kPeriodUs, kTimeoutUs};
  Eigen::VectorXd measured = Eigen::Vector2d(0.1, 0.2);
  std::string why;

  // One cycle: the answer (if any) comes, then the decision.
  void Cycle(int64_t k, const controller::JointCommand* answer) {
    if (answer != nullptr) {
      ASSERT_TRUE(gate.Offer(*answer, k, &why)) << why;
    }
    gate.Decide(k, measured);
  }
};

TEST_F(CommandGateTest, HoldsTheStartPostureUntilTheFirstCommand) {
  Cycle(0, nullptr);
  EXPECT_TRUE(gate.holding());
  EXPECT_EQ(gate.reason(), HoldReason::kNoCommandYet);
  EXPECT_EQ(gate.q(), measured);
  EXPECT_TRUE(gate.v().isZero());
  measured = Eigen::Vector2d(0.3, 0.4);  // sagging: the hold stays where it began
  Cycle(1, nullptr);
  EXPECT_EQ(gate.q(), Eigen::Vector2d(0.1, 0.2));
  EXPECT_EQ(gate.holds(), 0);  // not a hold the watchdog engaged
}

TEST_F(CommandGateTest, AppliesTheFreshCommand) {
  for (int k = 0; k < 5; ++k) {
    const auto c = Answer(k, 0.01 * k);
    Cycle(k, &c);
    EXPECT_FALSE(gate.holding());
    EXPECT_FALSE(gate.late());
    EXPECT_EQ(gate.applied_sequence(), k);
    EXPECT_DOUBLE_EQ(gate.q()[0], 0.01 * k);
    EXPECT_DOUBLE_EQ(gate.v()[1], -0.5);
  }
  EXPECT_EQ(gate.commands_taken(), 5);
  EXPECT_EQ(gate.commands_late(), 0);
  EXPECT_EQ(gate.holds(), 0);
}

TEST_F(CommandGateTest, ALateCycleRunsOnThePreviousCommandAndCounts) {
  const auto c0 = Answer(0, 0.5);
  Cycle(0, &c0);
  Cycle(1, nullptr);  // the answer to 1 did not come in time
  EXPECT_FALSE(gate.holding());
  EXPECT_TRUE(gate.late());
  EXPECT_EQ(gate.applied_sequence(), 0);
  EXPECT_DOUBLE_EQ(gate.q()[0], 0.5);
  EXPECT_EQ(gate.commands_late(), 1);
  // It comes during cycle 2, before 2's own: applied, still late.
  const auto c1 = Answer(1, 0.6);
  Cycle(2, &c1);
  EXPECT_TRUE(gate.late());
  EXPECT_DOUBLE_EQ(gate.q()[0], 0.6);
  EXPECT_EQ(gate.commands_late(), 2);
  // Then 3's on time; 2's, coming after it, is refused as out of order.
  const auto c3 = Answer(3, 0.8);
  Cycle(3, &c3);
  EXPECT_FALSE(gate.late());
  EXPECT_FALSE(gate.Offer(Answer(2, 0.7), 4, &why));
  EXPECT_NE(why.find("out of order"), std::string::npos) << why;
  EXPECT_EQ(gate.commands_late(), 2);
}

TEST_F(CommandGateTest, HoldsWhereTheRobotIsWhenTheNewestCommandIsOlderThanTheTimeout) {
  const auto c0 = Answer(0, 0.5);
  Cycle(0, &c0);
  for (int k = 1; k < 10; ++k) {  // 1..9 ms old: still applied, late
    measured = Eigen::Vector2d(0.5 + 0.001 * k, -0.5);
    Cycle(k, nullptr);
    EXPECT_FALSE(gate.holding()) << k;
    EXPECT_DOUBLE_EQ(gate.q()[0], 0.5);
  }
  measured = Eigen::Vector2d(0.52, -0.49);
  Cycle(10, nullptr);  // 10 ms old: hold
  EXPECT_TRUE(gate.holding());
  EXPECT_EQ(gate.reason(), HoldReason::kTimeout);
  EXPECT_EQ(gate.q(), measured);
  EXPECT_TRUE(gate.v().isZero());
  EXPECT_EQ(gate.holds(), 1);
  EXPECT_DOUBLE_EQ(gate.last_hold_reaction_ms(), 10.0);  // received at 0 ms, hold at 10 ms
  EXPECT_EQ(gate.command_age_us(), 10000);
  EXPECT_EQ(gate.commands_late(), 9);  // the hold's cycles are not late: they hold
  // The hold stays where it began.
  const Eigen::VectorXd held = measured;
  measured = Eigen::Vector2d(0.0, 0.0);
  Cycle(11, nullptr);
  EXPECT_EQ(gate.q(), held);
  EXPECT_EQ(gate.holds(), 1);
  // A command resumes tracking.
  const auto c12 = Answer(12, 0.3);
  Cycle(12, &c12);
  EXPECT_FALSE(gate.holding());
  EXPECT_DOUBLE_EQ(gate.q()[0], 0.3);
  // A second silence is a second hold, its reaction measured from the last receipt (12 ms).
  for (int k = 13; k <= 30; ++k) Cycle(k, nullptr);
  EXPECT_EQ(gate.holds(), 2);
  EXPECT_DOUBLE_EQ(gate.last_hold_reaction_ms(), 10.0);
}

TEST_F(CommandGateTest, ALateAnswerResetsTheWatchdogByItsStateTime) {
  const auto c0 = Answer(0, 0.5);
  Cycle(0, &c0);
  for (int k = 1; k < 9; ++k) Cycle(k, nullptr);
  // Cycle 9 receives the answer to 8: 1 ms old, applied.
  const auto c8 = Answer(8, 0.4);
  Cycle(9, &c8);
  EXPECT_FALSE(gate.holding());
  EXPECT_DOUBLE_EQ(gate.q()[0], 0.4);
  EXPECT_EQ(gate.command_age_us(), 1000);
}

TEST_F(CommandGateTest, ModeOneHoldsAndModeZeroResumes) {
  const auto c0 = Answer(0, 0.5);
  Cycle(0, &c0);
  measured = Eigen::Vector2d(0.45, -0.45);
  const auto c1 = Answer(1, 0.9, /*mode=*/1);
  Cycle(1, &c1);
  EXPECT_TRUE(gate.holding());
  EXPECT_EQ(gate.reason(), HoldReason::kRequested);
  EXPECT_EQ(gate.q(), measured);  // where the robot is, not the command's targets
  EXPECT_TRUE(gate.v().isZero());
  EXPECT_EQ(gate.holds(), 1);
  EXPECT_DOUBLE_EQ(gate.last_hold_reaction_ms(), 0.0);  // a requested hold is not the watchdog's
  const auto c2 = Answer(2, 0.9, /*mode=*/1);
  Cycle(2, &c2);
  EXPECT_EQ(gate.holds(), 1);  // one hold, still engaged
  EXPECT_EQ(gate.q(), Eigen::Vector2d(0.45, -0.45));
  const auto c3 = Answer(3, 0.7);
  Cycle(3, &c3);
  EXPECT_FALSE(gate.holding());
  EXPECT_DOUBLE_EQ(gate.q()[0], 0.7);
  EXPECT_EQ(gate.commands_taken(), 4);
}

TEST_F(CommandGateTest, RefusesWhatAnswersNoStateOfThisDriver) {
  const auto c0 = Answer(0, 0.5);
  Cycle(0, &c0);
  EXPECT_FALSE(gate.Offer(Answer(0, 0.5), 1, &why));  // the same again
  EXPECT_NE(why.find("duplicated"), std::string::npos) << why;
  EXPECT_FALSE(gate.Offer(Answer(5, 0.5), 1, &why));  // a state not published yet
  EXPECT_NE(why.find("answers no state yet"), std::string::npos) << why;
  auto wrong_clock = Answer(1, 0.5);
  wrong_clock.utime += 7;
  EXPECT_FALSE(gate.Offer(wrong_clock, 1, &why));
  EXPECT_NE(why.find("utime"), std::string::npos) << why;
  controller::JointCommand wrong_size = Answer(1, 0.5);
  wrong_size.q = Eigen::Vector3d::Zero();
  EXPECT_FALSE(gate.Offer(wrong_size, 1, &why));
  // Nothing refused changed the decision.
  gate.Decide(1, measured);
  EXPECT_TRUE(gate.late());
  EXPECT_DOUBLE_EQ(gate.q()[0], 0.5);
  EXPECT_EQ(gate.commands_taken(), 1);
}

TEST_F(CommandGateTest, ZeroTimeoutHoldsAtTheFirstMissingAnswer) {
  CommandGate strict(2, 2, kPeriodUs, 0);
  const auto c0 = Answer(0, 0.5);
  ASSERT_TRUE(strict.Offer(c0, 0, &why));
  strict.Decide(0, measured);
  EXPECT_FALSE(strict.holding());
  strict.Decide(1, measured);
  EXPECT_TRUE(strict.holding());
  EXPECT_DOUBLE_EQ(strict.last_hold_reaction_ms(), 1.0);
}

TEST_F(CommandGateTest, NoAllocationPerCycle) {
  const auto c0 = Answer(0, 0.5);
  Cycle(0, &c0);
  std::vector<controller::JointCommand> answers;
  for (int k = 1; k < 40; ++k) answers.push_back(Answer(k, 0.01 * k, k % 7 == 0 ? 1 : 0));
  testing::ScopedAllocationCounter counter;
  for (int k = 1; k < 40; ++k) {
    if (k % 3 != 0 && k < 20) {
      ASSERT_TRUE(gate.Offer(answers[k - 1], k, &why));
    }
    gate.Decide(k, measured);  // fresh, late, hold requested, watchdog hold (20..)
  }
  EXPECT_EQ(counter.allocations(), 0);
  EXPECT_TRUE(gate.holding());
}

}  // namespace
}  // namespace marionette::sim_driver
