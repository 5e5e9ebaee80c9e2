// Swing-foot trajectories against their closed form: end placements, flat lift-off and landing
// (zero velocity and acceleration), apex, velocities against finite differences, via points.
#include <gtest/gtest.h>

#include <cmath>

#include "marionette/walk/swing_foot.h"

namespace marionette::walk {
namespace {

TEST(SwingFootTest, StartsAndLandsFlatWithZeroVelocityAndAcceleration) {
  const FootPlacement from(0.0, 0.1, 0.0, 0.2), to(0.25, 0.15, 0.02, -0.3);
  const SwingFoot swing(from, to, 0.8, 0.05);
  for (double t : {0.0, 0.8}) {
    const FootSample s = swing.Sample(t);
    const FootPlacement expected = t == 0.0 ? from : to;
    EXPECT_LT((PoseToPlacement(s.pose) - expected).norm(), 1e-12) << t;
    EXPECT_LT(s.velocity.norm(), 1e-12) << t;
    EXPECT_LT(s.acceleration.norm(), 1e-12) << t;
    EXPECT_NEAR(s.pose.rotation()(2, 2), 1.0, 1e-15) << "the sole stays flat";
  }
  // Apex at mid-swing: b(½) = 1 above the straight line, σ(½) = ½ along it.
  const FootSample mid = swing.Sample(0.4);
  EXPECT_NEAR(mid.pose.translation().z(), 0.01 + 0.05, 1e-12);
  EXPECT_NEAR(mid.pose.translation().x(), 0.125, 1e-12);
  EXPECT_NEAR(PoseToPlacement(mid.pose)[3], -0.05, 1e-12);
}

TEST(SwingFootTest, VelocityAndAccelerationAreTheDerivativesOfThePose) {
  const SwingFoot swing(FootPlacement(0.0, 0.1, 0.0, 3.0), FootPlacement(0.2, 0.0, 0.0, -3.0), 0.7,
                        0.06);
  const double h = 1e-5;
  for (double t = 0.05; t < 0.7; t += 0.1) {
    const FootSample a = swing.Sample(t - h), b = swing.Sample(t), c = swing.Sample(t + h);
    const FootPlacement pa = PoseToPlacement(a.pose), pb = PoseToPlacement(b.pose),
                        pc = PoseToPlacement(c.pose);
    Eigen::Vector4d rate = (pc - pa) / (2 * h);
    rate[3] = WrapAngle(pc[3] - pa[3]) / (2 * h);  // through ±π: the short way (Δyaw = 0.28 rad)
    Eigen::Vector4d accel = (pc - 2 * pb + pa) / (h * h);
    accel[3] = (WrapAngle(pc[3] - pb[3]) - WrapAngle(pb[3] - pa[3])) / (h * h);
    EXPECT_LT((rate.head<3>() - b.velocity.head<3>()).norm(), 1e-6) << t;
    EXPECT_NEAR(rate[3], b.velocity[5], 1e-6) << t;
    EXPECT_LT((accel.head<3>() - b.acceleration.head<3>()).norm(), 1e-3) << t;
    EXPECT_NEAR(accel[3], b.acceleration[5], 1e-3) << t;
    EXPECT_LT(std::abs(b.velocity[5]), 2.0) << "turns by 0.28 rad, not by 2π − 0.28";
  }
}

TEST(SwingFootTest, ViaPointRaisesTheSwingAboveIt) {
  const FootPlacement from(0.0, 0.0, 0.0, 0.0), to(0.4, 0.0, 0.0, 0.0);
  const Eigen::Vector3d bar(0.1, 0.0, 0.12);  // above the requested 0.05 m apex, a quarter along
  const SwingFoot swing(from, to, 1.0, 0.05, &bar, 1);
  EXPECT_GT(swing.height(), 0.12);
  // Where the foot crosses x = 0.1 it is at the via point's height (the minimum that clears it).
  double lo = 0.0, hi = 1.0;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (swing.Sample(mid).pose.translation().x() < 0.1 ? lo : hi) = mid;
  }
  EXPECT_NEAR(swing.Sample(lo).pose.translation().z(), 0.12, 1e-6);
  EXPECT_THROW(SwingFoot(from, to, 0.0, 0.05), std::invalid_argument);
  EXPECT_THROW(SwingFoot(from, to, 1.0, -0.01), std::invalid_argument);
}

}  // namespace
}  // namespace marionette::walk
