// A full TALOS stack tick (kinematics, 7 features, 7 tasks, the 4-level solver with joint
// limits, the kinematic device) allocates nothing and takes no lock after warm-up
// (STYLE.md rule 4).
#include <gtest/gtest.h>

#include "allocation_counter.h"
#include "talos_stack.h"

namespace marionette::sot {
namespace {

TEST(SotRealtimeTest, TalosStackTickAllocatesNothingAfterWarmUp) {
  testing::TalosStack s = testing::BuildTalosStack();
  graph::Tick tick;
  graph::RunTicks(*s.graph, &tick, 100);
  int qp = 0;
  marionette::testing::ScopedAllocationCounter counter;
  for (int i = 0; i < 2000; ++i, ++tick) {
    s.graph->Evaluate(tick);
    qp += s.solver->report().num_qp;
  }
  EXPECT_EQ(counter.allocations(), 0);
  EXPECT_EQ(counter.locks(), 0);
  EXPECT_EQ(qp, 0);  // the nominal path: no inequality binds on this reach
  EXPECT_TRUE(s.solver->velocity_output().value().allFinite());
}

}  // namespace
}  // namespace marionette::sot
