// The footstep manager alone (fixed inputs, evaluated outputs) and with the pattern generator:
// timeline, ZMP reference and window, replanning rules, the CoM's cart-table ZMP against the
// reference, and an allocation-free tick.
#include <gtest/gtest.h>

#include <cmath>

#include "allocation_counter.h"
#include "marionette/graph/graph.h"
#include "marionette/walk/footstep_manager.h"
#include "marionette/walk/pattern_generator.h"

namespace marionette::walk {
namespace {

const FootPlacement kLeft(0.0, 0.085, 0.0, 0.0), kRight(0.0, -0.085, 0.0, 0.0);

// `count` steps forward of `length`, right foot first, from index `first`.
FootstepPlan Forward(int count, double length, int first = 0, int64_t id = 1) {
  FootstepPlan plan;
  plan.plan_id = id;
  plan.first_step_index = first;
  plan.num_steps = count;
  for (int k = 0; k < count; ++k) {
    Footstep& s = plan.steps[k];
    s.index = first + k;
    s.is_left = (first + k) % 2 == 1;
    const double x = std::min(length * (first + k + 1), length * (first + count));
    s.placement << x, s.is_left ? 0.085 : -0.085, 0.0, 0.0;
    s.single_support = 0.8;
    s.double_support = 0.2;
    s.step_height = 0.05;
  }
  return plan;
}

struct Rig {
  explicit Rig(FootstepManagerOptions options = {}) {
    graph::GraphBuilder b;
    manager = &b.Add<FootstepManager>("steps", kLeft, kRight, Eigen::Vector2d(0.01, 0.0), options);
    graph = b.Build();
  }
  void Run(double until) {
    for (; tick.time < until - 1e-9; ++tick) graph->Evaluate(tick);
  }
  // Evaluates the tick at or after the last Run (poll included) and pulls every output.
  void Eval() {
    graph->Evaluate(tick);
    for (graph::SignalBase* s : manager->outputs()) s->Pull(tick);
    ++tick;
  }
  FootstepManager* manager;
  std::unique_ptr<graph::Graph> graph;
  graph::Tick tick;
};

TEST(FootstepManagerTest, WalksThePlanPhaseByPhase) {
  FootstepManagerOptions options;
  options.min_first_double_support = 0.5;
  options.final_double_support = 0.6;
  options.start_delay = 0.0;
  Rig rig(options);
  rig.Run(0.1);
  EXPECT_EQ(rig.manager->phase_output().value(), static_cast<int>(WalkPhase::kStanding));
  EXPECT_EQ(rig.manager->step_index_output().value(), -1);
  ASSERT_TRUE(rig.manager->Post(Forward(3, 0.2)));
  // Plan applied at t = 0.1: step 0 = 0.5 s double support (the first one is lengthened),
  // 0.8 s right swing; steps 1, 2 = 0.2 + 0.8 s; final 0.6 s double support.
  struct Expect {
    double time;
    WalkPhase phase;
    int index;
    int support;
  };
  for (const Expect& e :
       {Expect{0.3, WalkPhase::kDoubleSupport, 0, 3}, Expect{0.7, WalkPhase::kRightSwing, 0, 1},
        Expect{1.45, WalkPhase::kDoubleSupport, 1, 3}, Expect{1.7, WalkPhase::kLeftSwing, 1, 2},
        Expect{2.7, WalkPhase::kRightSwing, 2, 1}, Expect{3.5, WalkPhase::kDoubleSupport, -1, 3},
        Expect{4.1, WalkPhase::kStanding, -1, 3}}) {
    rig.Run(e.time);
    rig.Eval();
    EXPECT_EQ(rig.manager->phase_output().value(), static_cast<int>(e.phase)) << e.time;
    EXPECT_EQ(rig.manager->step_index_output().value(), e.index) << e.time;
    EXPECT_EQ(rig.manager->support_output().value(), e.support) << e.time;
  }
  // The feet landed where planned; the ZMP reference rests between them.
  EXPECT_LT(
      (PoseToPlacement(rig.manager->left_foot_output().value()) - FootPlacement(0.4, 0.085, 0, 0))
          .norm(),
      1e-12);
  EXPECT_LT(
      (PoseToPlacement(rig.manager->right_foot_output().value()) - FootPlacement(0.6, -0.085, 0, 0))
          .norm(),
      1e-12);
  EXPECT_LT((rig.manager->zmp_reference_output().value() - Eigen::Vector2d(0.5, 0.0)).norm(),
            1e-12);
  EXPECT_EQ(rig.manager->completed_steps(), 3);
}

TEST(FootstepManagerTest, ZmpReferenceSitsOnTheSupportFootAndTheWindowIsTheFuture) {
  FootstepManagerOptions options;
  options.start_delay = 0.0;  // the first swing (0.6 .. 1.4 s) inside the window seen at 0.5 s
  Rig rig(options);
  rig.manager->Post(Forward(4, 0.15));
  rig.Run(0.5);
  rig.Eval();
  const Eigen::MatrixXd window = rig.manager->zmp_window_output().value();  // seen at t = 0.5
  ASSERT_EQ(window.cols(), 1601);
  for (int j = 50; j <= 1600; j += 50) {
    rig.Run(0.5 + j * 1e-3);
    rig.Eval();
    EXPECT_LT((rig.manager->zmp_reference_output().value() - window.col(j)).norm(), 1e-9) << j;
    if (rig.manager->phase_output().value() == static_cast<int>(WalkPhase::kRightSwing)) {
      // single support on the left foot: the ZMP reference is its centre
      EXPECT_LT((window.col(j) - kLeft.head<2>()).norm(), 1e-12) << j;
    }
  }
}

// The waist faces halfway between the feet through a turning walk (each foot turns by 0.3 rad
// per step, alternately), as it stood at the start (HoldWaist: 0.02 rad of yaw off the feet's
// mean, pitched 0.01 rad): its yaw is the mean of the feet's yaws + 0.02 at every tick, its pitch
// stays 0.01, and its yaw rate is the central difference of its yaw (1e-4 rad/s), as a reference
// and its feed-forward must be.
TEST(FootstepManagerTest, TheWaistFacesHalfwayBetweenTheFeetAndItsRateIsItsDerivative) {
  FootstepManagerOptions options;
  options.start_delay = 0.0;
  Rig rig(options);
  FootstepPlan plan = Forward(4, 0.15);
  for (int k = 0; k < plan.num_steps; ++k) plan.steps[k].placement[3] = 0.3 * ((k + 1) / 2 + 1);
  rig.manager->HoldWaist(  // the standing feet face 0
      (Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitZ()) *
       Eigen::AngleAxisd(0.01, Eigen::Vector3d::UnitY()))
          .toRotationMatrix());
  rig.manager->Post(plan);
  auto yaw = [](const pinocchio::SE3& X) {
    return std::atan2(X.rotation()(1, 0), X.rotation()(0, 0));
  };
  double before = 0.0, previous = 0.0, previous_rate = 0.0, max_rate_error = 0.0, turned = 0.0;
  for (int j = 0; j < 6000; ++j) {
    rig.Eval();
    const double waist = yaw(rig.manager->waist_output().value());
    const double mean = 0.5 * (yaw(rig.manager->left_foot_output().value()) +
                               yaw(rig.manager->right_foot_output().value()));
    ASSERT_NEAR(waist, mean + 0.02, 1e-12) << j;
    ASSERT_NEAR(rig.manager->waist_output().value().rotation()(2, 2), std::cos(0.01), 1e-12) << j;
    const Eigen::VectorXd& v = rig.manager->waist_velocity_output().value();
    ASSERT_NEAR(v[3], 0.0, 1e-12);
    ASSERT_NEAR(v[4], 0.0, 1e-12);
    if (j > 1) {
      const double central = (waist - before) / 2e-3;  // the rate at the previous tick
      max_rate_error = std::max(max_rate_error, std::abs(central - previous_rate));
    }
    before = previous, previous = waist, previous_rate = v[5];
    turned = std::max(turned, waist);
  }
  EXPECT_LT(max_rate_error, 1e-4);
  EXPECT_GT(turned, 0.5);  // the walk did turn
}

TEST(FootstepManagerTest, ReplanningNeverChangesTheStepInProgress) {
  Rig rig;
  rig.manager->Post(Forward(4, 0.15));
  rig.Run(1.5);  // step 0 in progress (1.6 s start delay, 0.6 s double support)
  ASSERT_EQ(rig.manager->queued(0).index, 0);
  FootstepPlan replan = Forward(4, 0.25, /*first=*/0, /*id=*/2);  // moves step 0 too
  rig.manager->Post(replan);
  rig.Run(1.6);
  EXPECT_NEAR(rig.manager->queued(0).placement.x(), 0.15, 1e-12) << "step 0 kept";
  EXPECT_NEAR(rig.manager->queued(1).placement.x(), 0.50, 1e-12) << "step 1 replanned";
  EXPECT_EQ(rig.manager->applied_plans(), 2);
  // A plan that leaves a gap after the queue's last step is refused whole.
  rig.manager->Post(Forward(2, 0.25, /*first=*/9, /*id=*/3));
  rig.Run(1.7);
  EXPECT_EQ(rig.manager->refused_plans(), 1);
  EXPECT_EQ(rig.manager->plan_id_output().Eval(rig.tick), 2);
  // A shorter plan from step 2 on drops the steps after it (the walk stops earlier).
  FootstepPlan shorter = Forward(1, 0.25, /*first=*/2, /*id=*/4);
  rig.manager->Post(shorter);
  rig.Run(1.8);
  EXPECT_EQ(rig.manager->num_queued(), 3);
  EXPECT_EQ(rig.manager->queued(2).index, 2);
  EXPECT_NEAR(rig.manager->queued(2).placement.x(), 0.75, 1e-12);
}

TEST(FootstepManagerTest, StopAfterCurrentStepLandsItStandsAndRefusesPlans) {
  FootstepManagerOptions options;
  options.start_delay = 0.0;
  options.min_first_double_support = 0.2;
  options.final_double_support = 0.6;
  Rig rig(options);
  rig.manager->Post(Forward(4, 0.2));
  rig.Run(1.5);  // step 0: 0.2 s double support + 0.8 s swing; step 1 (left) swinging since 1.2 s
  rig.Eval();
  ASSERT_EQ(rig.manager->step_index_output().value(), 1);
  ASSERT_EQ(rig.manager->phase_output().value(), static_cast<int>(WalkPhase::kLeftSwing));
  rig.manager->StopAfterCurrentStep();  // what the hold controller does at its swap
  EXPECT_EQ(rig.manager->num_queued(), 1);
  rig.manager->Post(Forward(4, 0.3, /*first=*/2, /*id=*/2));
  rig.Run(4.0);  // step 1 lands at 2.0 s, 0.6 s of final double support
  rig.Eval();
  EXPECT_EQ(rig.manager->phase_output().value(), static_cast<int>(WalkPhase::kStanding));
  EXPECT_EQ(rig.manager->completed_steps(), 2);
  EXPECT_EQ(rig.manager->refused_plans(), 1);
  // Step 1 landed where planned, the right foot stayed at step 0's place, the ZMP between them.
  EXPECT_LT(
      (PoseToPlacement(rig.manager->left_foot_output().value()) - FootPlacement(0.4, 0.085, 0, 0))
          .norm(),
      1e-12);
  EXPECT_LT(
      (PoseToPlacement(rig.manager->right_foot_output().value()) - FootPlacement(0.2, -0.085, 0, 0))
          .norm(),
      1e-12);
  EXPECT_LT((rig.manager->zmp_reference_output().value() - Eigen::Vector2d(0.3, 0.0)).norm(),
            1e-12);
}

TEST(FootstepManagerTest, ValidationNamesTheBadStep) {
  FootstepPlan plan = Forward(3, 0.2);
  EXPECT_EQ(ValidateFootstepPlan(plan), "");
  plan.steps[1].single_support = 0.0;
  EXPECT_NE(ValidateFootstepPlan(plan).find("step 1"), std::string::npos);
  plan = Forward(3, 0.2);
  plan.steps[2].index = 7;
  EXPECT_NE(ValidateFootstepPlan(plan).find("without gaps"), std::string::npos);
  plan = Forward(3, 0.2);
  plan.steps[0].placement[1] = std::nan("");
  EXPECT_NE(ValidateFootstepPlan(plan).find("non-finite"), std::string::npos);
}

// The pattern generator after the manager: the CoM's cart-table ZMP, from the CoM trajectory by
// finite differences (p = c − z_c/g c̈, eq. 2.51), follows the reference, and the tick allocates
// nothing.
TEST(PatternGeneratorTest, CartTableZmpOfTheComFollowsTheReference) {
  graph::GraphBuilder b;
  FootstepManagerOptions options;
  auto& manager =
      b.Add<FootstepManager>("steps", kLeft, kRight, Eigen::Vector2d(0.0, 0.0), options);
  PreviewControlParams params;
  params.com_height = 0.87;
  auto& pg = b.Add<PatternGenerator>("pg", params, Eigen::Vector3d(0.0, 0.0, 0.87));
  b.Connect(manager.zmp_window_output(), pg.zmp_window_input());
  auto graph = b.Build();
  manager.Post(Forward(8, 0.2));
  graph::Tick t;
  std::vector<Eigen::Vector2d> com, reference;
  com.reserve(20000);
  reference.reserve(20000);
  double max_error = 0.0, max_lateral = 0.0;
  int64_t allocations = 0;
  for (; t.time < 12.0; ++t) {
    if (t.index == 2000) {
      marionette::testing::ScopedAllocationCounter counter;
      for (int i = 0; i < 1000; ++i, ++t) {
        graph->Evaluate(t);
        com.push_back(pg.com_output().Eval(t).head<2>());
        reference.push_back(manager.zmp_reference_output().Eval(t));
      }
      allocations = counter.allocations();
    }
    graph->Evaluate(t);
    com.push_back(pg.com_output().Eval(t).head<2>());
    reference.push_back(manager.zmp_reference_output().Eval(t));
  }
  EXPECT_EQ(allocations, 0);
  const double dt = 1e-3, zc = 0.87, g = 9.81;
  for (size_t k = 1; k + 1 < com.size(); ++k) {
    const Eigen::Vector2d accel = (com[k + 1] - 2 * com[k] + com[k - 1]) / (dt * dt);
    const Eigen::Vector2d zmp = com[k] - zc / g * accel;
    max_error = std::max(max_error, (zmp - reference[k]).norm());
    max_lateral = std::max(max_lateral, std::abs(com[k].y()));
  }
  std::printf("cart-table ZMP of the CoM vs reference: max %.1f mm; CoM lateral swing %.1f mm\n",
              1e3 * max_error, 1e3 * max_lateral);
  EXPECT_LT(max_error, 0.01);
  EXPECT_GT(max_lateral, 0.02);   // the CoM does swing towards the support feet...
  EXPECT_LT(max_lateral, 0.085);  // ...without reaching them (a dynamic walk, fig. 2.16)
  EXPECT_LT((com.back() - Eigen::Vector2d(1.5, 0.0)).norm(), 1e-3)
      << "at rest between the final feet";
}

}  // namespace
}  // namespace marionette::walk
