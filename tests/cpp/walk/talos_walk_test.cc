// TALOS walks in MuJoCo: the footstep manager and the preview-control pattern
// generator drive the feet and CoM tasks of the stack; the robot walks 10 steps forward, walks
// a turn, and stops, without falling; the feet land where planned; the ZMP measured from the
// soles' contact wrenches stays inside the support polygon.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "allocation_counter.h"
#include "talos_walk_rig.h"

namespace marionette::walk {
namespace {

const std::string kModels = MARIONETTE_MODELS_DIR;

// [m] How far outside its sole's edge the measured ZMP of a sole rolling on that edge may read:
// MuJoCo puts contact points mid-penetration, below the plane the ZMP is taken on, and the shear
// forces' moment over that sub-millimetre height moves it by micrometres (seen in the 90° turn
// once that moment had the right sign: 14 of 14002 samples outside, the farthest by 6 µm).
constexpr double kContactFuzz = 1e-4;

struct WalkRecord {
  double min_base_height = 1e9, max_base_height = -1e9;
  double min_zmp_margin = 1e9;     // signed distance of the measured ZMP to the support polygon [m]
  double worst_landing = 0.0;      // [m] planned vs landed sole position
  double worst_landing_yaw = 0.0;  // [rad]
  int zmp_samples = 0;
  int outside_samples = 0;      // margin < -kContactFuzz: the ZMP left the soles
  int edge_samples = 0;         // margin < 2 mm: the sole is rolling on an edge
  std::vector<double> margins;  // every sample's margin [m]
  double MarginQuantile(double q) const {
    std::vector<double> m = margins;
    std::sort(m.begin(), m.end());
    return m.empty() ? 0.0 : m[static_cast<size_t>(q * (m.size() - 1))];
  }
};

// Runs the rig until the walk has ended and `settle` seconds more, checking every tick. When
// `replan` is given it is posted as soon as `replan_after` steps are completed (landing checks
// then follow its steps).
WalkRecord Walk(testing::WalkRig& rig, const FootstepPlan& plan, double settle = 1.0,
                const FootstepPlan* replan = nullptr, int replan_after = 0) {
  FootstepPlan executed = plan;  // the steps as they will be walked
  WalkRecord rec;
  for (int i = 0; i < 500; ++i) rig.Step();  // stand first
  rig.steps->Post(plan);
  const double ground = 0.0;
  double standing_since = -1.0;
  int64_t completed = rig.steps->completed_steps();
  const double timeout = rig.tick.time + 60.0;
  // MARIONETTE_WALK_TRACE=file.csv: every 10th tick, for plots and diagnosis.
  const char* trace_path = std::getenv("MARIONETTE_WALK_TRACE");
  FILE* trace = trace_path ? std::fopen(trace_path, "w") : nullptr;
  if (trace)
    std::fprintf(trace,
                 "t,phase,base_x,base_y,base_z,base_qx,base_qy,com_x,com_y,com_ref_x,com_ref_y,zmp_"
                 "ref_x,zmp_ref_y,zmp_x,zmp_y,fz_left,fz_right\n");
  while (rig.tick.time < timeout) {
    rig.Step();
    const Eigen::VectorXd& q = rig.device->q_output().value();
    if (trace && rig.tick.index % 10 == 0) {
      SoleWrench w[2];
      rig.SoleWrenches(w);
      Eigen::Vector2d zmp(NAN, NAN);
      MeasuredZmp(w, 2, 0.0, &zmp);
      const Eigen::Vector3d com = rig.robot->kinematics_output().value().com();
      const Eigen::VectorXd& com_ref = rig.pg->com_output().value();
      const Eigen::VectorXd& zmp_ref = rig.steps->zmp_reference_output().value();
      std::fprintf(
          trace,
          "%.3f,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%.1f,%.1f\n",
          rig.tick.time, rig.steps->phase_output().value(), q[0], q[1], q[2], q[3], q[4], com[0],
          com[1], com_ref[0], com_ref[1], zmp_ref[0], zmp_ref[1], zmp[0], zmp[1], w[0].force.z(),
          w[1].force.z());
    }
    rec.min_base_height = std::min(rec.min_base_height, q[2]);
    rec.max_base_height = std::max(rec.max_base_height, q[2]);
    if (q[2] < 0.6) break;  // fallen
    // Landing check: at the tick a step completes, the landed foot against its placement.
    if (rig.steps->completed_steps() > completed) {
      completed = rig.steps->completed_steps();
      if (replan != nullptr && completed == replan_after) {
        rig.steps->Post(*replan);
        executed.num_steps = replan->first_step_index + replan->num_steps;
        for (int k = 0; k < replan->num_steps; ++k)
          executed.steps[replan->first_step_index + k] = replan->steps[k];
      }
      const int k = static_cast<int>(completed - 1);
      const Footstep& s = executed.steps[k];
      const FootPlacement landed =
          rig.SolePlacement(s.is_left ? FootstepManager::kLeft : FootstepManager::kRight);
      rec.worst_landing =
          std::max(rec.worst_landing, (landed.head<2>() - s.placement.head<2>()).norm());
      rec.worst_landing_yaw =
          std::max(rec.worst_landing_yaw, std::abs(WrapAngle(landed[3] - s.placement[3])));
    }
    // Measured ZMP against the polygon of the soles that carry load (ground truth poses).
    SoleWrench w[2];
    rig.SoleWrenches(w);
    Eigen::Vector2d zmp;
    if (MeasuredZmp(w, 2, ground, &zmp)) {
      FootPlacement loaded[2];
      int n = 0;
      for (int side = 0; side < 2; ++side) {
        if (w[side].force.z() > 10.0) loaded[n++] = rig.SolePlacement(side);
      }
      const double margin = SignedMargin(MakeSupportPolygon(loaded, n), zmp);
      rec.min_zmp_margin = std::min(rec.min_zmp_margin, margin);
      ++rec.zmp_samples;
      rec.margins.push_back(margin);
      if (margin < -kContactFuzz) ++rec.outside_samples;
      if (margin < 0.002) ++rec.edge_samples;
    }
    if (rig.steps->phase_output().value() == static_cast<int>(WalkPhase::kStanding) &&
        rig.steps->completed_steps() >= executed.num_steps) {
      if (standing_since < 0.0) standing_since = rig.tick.time;
      if (rig.tick.time - standing_since > settle) break;
    }
  }
  if (trace) std::fclose(trace);
  return rec;
}

FootstepPlan StraightPlan(const FootPlacement& left, const FootPlacement& right, int count,
                          double length) {
  FootstepPlan plan;
  plan.plan_id = 1;
  plan.num_steps = count;
  for (int k = 0; k < count; ++k) {
    Footstep& s = plan.steps[k];
    s.index = k;
    s.is_left = k % 2 == 1;  // right foot first
    const FootPlacement& start = s.is_left ? left : right;
    const double advance =
        std::min(length * (k + 1), length * (count - 1));  // last step closes the stance
    s.placement = start + FootPlacement(advance, 0.0, 0.0, 0.0);
    s.single_support = 0.8;
    s.double_support = 0.2;
    s.step_height = 0.05;
  }
  return plan;
}

// Turning on the spot around the midpoint of the feet by `dyaw` per step pair.
FootstepPlan TurnPlan(const FootPlacement& left, const FootPlacement& right, int count, double dyaw,
                      double advance) {
  FootstepPlan plan;
  plan.plan_id = 2;
  plan.num_steps = count;
  const Eigen::Vector2d centre = 0.5 * (left.head<2>() + right.head<2>());
  const double half_width = 0.5 * (left.head<2>() - right.head<2>()).norm();
  for (int k = 0; k < count; ++k) {
    Footstep& s = plan.steps[k];
    s.index = k;
    s.is_left = k % 2 == 0;  // turning left: the left foot leads
    const int pairs = std::min(k / 2 + 1, count / 2);
    const double yaw = left[3] + dyaw * pairs;
    const Eigen::Vector2d forward(std::cos(yaw), std::sin(yaw)),
        lateral(-std::sin(yaw), std::cos(yaw));
    const Eigen::Vector2d c = centre + advance * pairs * forward;
    const Eigen::Vector2d p = c + (s.is_left ? half_width : -half_width) * lateral;
    s.placement << p.x(), p.y(), left[2], yaw;
    s.single_support = 0.8;
    s.double_support = 0.2;
    s.step_height = 0.04;
  }
  return plan;
}

void Report(const char* name, const WalkRecord& r) {
  std::printf(
      "%s: base height %.3f..%.3f m, worst landing %.1f mm / %.2f deg, measured ZMP margin "
      "min %.3f mm, 1%% quantile %.1f mm, median %.1f mm (%d of %d samples within 2 mm of an edge, "
      "%d outside)\n",
      name, r.min_base_height, r.max_base_height, 1e3 * r.worst_landing,
      r.worst_landing_yaw * 180.0 / M_PI, 1e3 * r.min_zmp_margin, 1e3 * r.MarginQuantile(0.01),
      1e3 * r.MarginQuantile(0.5), r.edge_samples, r.zmp_samples, r.outside_samples);
}

// The rig's options for the robot alone on the floor, every other option at its default.
testing::WalkRigOptions TalosAlone() {
  testing::WalkRigOptions options;
  options.scene = kModels + "/talos/talos.xml";
  return options;
}

TEST(TalosWalkTest, TenStepsForwardAndStops) {
  testing::WalkRig rig = testing::BuildWalkRig(TalosAlone());
  const double base0 = rig.q0[2];
  const FootstepPlan plan = StraightPlan(rig.SolePlacement(0), rig.SolePlacement(1), 10, 0.15);
  const WalkRecord r = Walk(rig, plan);
  Report("10 steps of 0.15 m", r);
  EXPECT_EQ(rig.steps->completed_steps(), 10);
  EXPECT_GT(r.min_base_height, base0 - 0.05) << "fell or sank";
  EXPECT_LT(r.worst_landing, 0.02);
  EXPECT_LT(r.worst_landing_yaw, 0.05);
  EXPECT_EQ(r.outside_samples, 0) << "measured ZMP left the support polygon";
  EXPECT_GT(r.min_zmp_margin, 0.005);
  // Stopped: standing still between the final feet.
  const Eigen::VectorXd& v = rig.device->v_output().value();
  EXPECT_LT(v.head<3>().norm(), 0.02);
  EXPECT_NEAR(rig.device->q_output().value()[0] - rig.q0[0], 0.15 * 9, 0.05);
}

TEST(TalosWalkTest, TurnsByNinetyDegrees) {
  testing::WalkRig rig = testing::BuildWalkRig(TalosAlone());
  const double base0 = rig.q0[2];
  const FootstepPlan plan =
      TurnPlan(rig.SolePlacement(0), rig.SolePlacement(1), 10, M_PI / 10.0, 0.05);
  const WalkRecord r = Walk(rig, plan);
  Report("turn by 90 deg in 10 steps", r);
  EXPECT_EQ(rig.steps->completed_steps(), 10);
  EXPECT_GT(r.min_base_height, base0 - 0.05);
  EXPECT_LT(r.worst_landing, 0.02);
  EXPECT_LT(r.worst_landing_yaw, 0.05);
  EXPECT_EQ(r.outside_samples, 0) << "measured ZMP left the support polygon";
  // Landing turned feet roll briefly on a sole edge (tens of ms in 14 s): not a tip-over.
  EXPECT_GT(r.MarginQuantile(0.01), 0.003);
  const FootPlacement left = rig.SolePlacement(0);
  EXPECT_NEAR(WrapAngle(left[3] - M_PI / 2.0), 0.0, 0.05);
}

// The whole walking tick (MuJoCo device, measured base, kinematics, walk entities, 6 tasks, the
// solver) allocates nothing and takes no lock once walking (STYLE.md rule 4), plans included.
TEST(TalosWalkTest, WalkingTickAllocatesNothing) {
  testing::WalkRig rig = testing::BuildWalkRig(TalosAlone());
  FootstepPlan plan = StraightPlan(rig.SolePlacement(0), rig.SolePlacement(1), 6, 0.1);
  rig.steps->Post(plan);
  while (rig.steps->phase_output().value() != static_cast<int>(WalkPhase::kRightSwing)) rig.Step();
  for (int i = 0; i < 200; ++i) rig.Step();
  plan.plan_id = 2;
  plan.first_step_index =
      1;  // a replan of the steps not started, consumed inside the counted ticks
  plan.num_steps = 5;
  for (int k = 0; k < 5; ++k) plan.steps[k] = plan.steps[k + 1];
  marionette::testing::ScopedAllocationCounter counter;
  rig.steps->Post(plan);
  for (int i = 0; i < 1500; ++i) rig.Step();
  EXPECT_EQ(counter.allocations(), 0);
  EXPECT_EQ(counter.locks(), 0);
  EXPECT_EQ(rig.steps->applied_plans(), 2);
  EXPECT_GE(rig.steps->completed_steps(), 1);
}

// A replan during the walk that ends it two steps later: the step in progress is kept, the robot
// closes its stance on the new last step and stops there.
TEST(TalosWalkTest, StopsEarlyWhenThePlanIsShortened) {
  testing::WalkRig rig = testing::BuildWalkRig(TalosAlone());
  const FootstepPlan plan = StraightPlan(rig.SolePlacement(0), rig.SolePlacement(1), 10, 0.15);
  FootstepPlan stop;  // step 3 is in progress when 3 are completed; step 4 closes the stance
  stop.plan_id = 2;
  stop.first_step_index = 4;
  stop.num_steps = 1;
  stop.steps[0] = plan.steps[4];
  stop.steps[0].placement.x() = plan.steps[3].placement.x();
  const WalkRecord r = Walk(rig, plan, 1.0, &stop, 3);
  Report("stop after 5 of 10 steps", r);
  EXPECT_EQ(rig.steps->completed_steps(), 5);
  EXPECT_EQ(r.outside_samples, 0);
  EXPECT_LT(r.worst_landing, 0.02);
  EXPECT_LT(rig.device->v_output().value().head<3>().norm(), 0.02);
  EXPECT_NEAR(rig.device->q_output().value()[0] - rig.q0[0], 0.15 * 4, 0.05);
}

}  // namespace
}  // namespace marionette::walk
