// Swing-foot trajectories against their closed form: end placements, flat lift-off and landing
// (zero velocity and acceleration), apex, velocities against finite differences, via points
// (rise, level crossing, landing).
#include <gtest/gtest.h>

#include <array>
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

// Finite differences of the pose against the sample's velocity and acceleration over a swing.
void ExpectDerivativesOfThePose(const SwingFoot& swing) {
  const double h = 1e-5, duration = swing.duration();
  for (double t = 0.013; t < duration; t += duration / 37.0) {
    const FootSample a = swing.Sample(t - h), b = swing.Sample(t), c = swing.Sample(t + h);
    const FootPlacement pa = PoseToPlacement(a.pose), pb = PoseToPlacement(b.pose),
                        pc = PoseToPlacement(c.pose);
    Eigen::Vector4d rate = (pc - pa) / (2 * h);
    rate[3] = WrapAngle(pc[3] - pa[3]) / (2 * h);  // through ±π: the short way
    Eigen::Vector4d accel = (pc - 2 * pb + pa) / (h * h);
    accel[3] = (WrapAngle(pc[3] - pb[3]) - WrapAngle(pb[3] - pa[3])) / (h * h);
    EXPECT_LT((rate.head<3>() - b.velocity.head<3>()).norm(), 1e-6) << t;
    EXPECT_NEAR(rate[3], b.velocity[5], 1e-6) << t;
    EXPECT_LT((accel.head<3>() - b.acceleration.head<3>()).norm(), 2e-3) << t;
    EXPECT_NEAR(accel[3], b.acceleration[5], 2e-3) << t;
    EXPECT_LT(std::abs(b.velocity[5]), 2.0) << "turns by 0.28 rad, not by 2π − 0.28";
  }
}

TEST(SwingFootTest, VelocityAndAccelerationAreTheDerivativesOfThePose) {
  const FootPlacement from(0.0, 0.1, 0.0, 3.0), to(0.2, 0.0, 0.02, -3.0);
  ExpectDerivativesOfThePose(SwingFoot(from, to, 0.7, 0.06));
  const Eigen::Vector3d over(0.1, 0.05, 0.15);
  ExpectDerivativesOfThePose(SwingFoot(from, to, 1.2, 0.06, &over, 1));
}

TEST(SwingFootTest, OverAViaPointTheSoleRisesCrossesLevelAndLands) {
  const FootPlacement from(0.0, 0.0, 0.0, 0.1), to(0.45, 0.05, 0.01, -0.1);
  // TALOS' trailing leg over a bar it lands 3 cm past: passage points at 0 % and 93 % of the
  // line, 0.149 m up.
  const std::array<Eigen::Vector3d, 2> via = {Eigen::Vector3d(0.0, 0.0, 0.149),
                                              Eigen::Vector3d(0.4185, 0.0465, 0.149)};
  const SwingFoot swing(from, to, 1.2, 0.05, via.data(), 2);
  EXPECT_NEAR(swing.height(), 0.149, 1e-12) << "the highest passage point, and no higher";
  const double r = SwingFoot::kRiseFraction;
  for (int i = 0; i <= 1200; ++i) {
    const double t = 1.2 * i / 1200.0, s = t / 1.2;
    const FootPlacement p = PoseToPlacement(swing.Sample(t).pose);
    const double along = (p.head<2>() - from.head<2>()).dot((to - from).head<2>()) /
                         (to - from).head<2>().squaredNorm();
    const double line = from[2] + (to[2] - from[2]) * along;
    if (s <= r) {
      EXPECT_LT((p.head<2>() - from.head<2>()).norm(), 1e-12) << "rises in place " << t;
    } else if (s >= 1.0 - r) {
      EXPECT_LT((p.head<2>() - to.head<2>()).norm(), 1e-12) << "lands in place " << t;
    } else {
      EXPECT_NEAR(p[2] - line, 0.149, 1e-12) << "level crossing " << t;
    }
    EXPECT_GE(p[2] - line, -1e-12) << t;
    // Above each passage point wherever the sole passes its horizontal position.
    for (const Eigen::Vector3d& v : via) {
      const double fraction = (v.head<2>() - from.head<2>()).dot((to - from).head<2>()) /
                              (to - from).head<2>().squaredNorm();
      if (std::abs(along - fraction) < 1e-3 && s > r && s < 1.0 - r) {
        EXPECT_GE(p[2], v.z() - 1e-9) << t;
      }
    }
  }
  for (double t : {0.0, 1.2}) {  // at rest at both ends, flat
    const FootSample e = swing.Sample(t);
    EXPECT_LT(e.velocity.norm(), 1e-12) << t;
    EXPECT_LT(e.acceleration.norm(), 1e-12) << t;
  }
}

TEST(SwingFootTest, ViaPointRaisesTheSwingAboveIt) {
  const FootPlacement from(0.0, 0.0, 0.0, 0.0), to(0.4, 0.0, 0.0, 0.0);
  const Eigen::Vector3d bar(0.1, 0.0, 0.12);  // above the requested 0.05 m apex, a quarter along
  const SwingFoot swing(from, to, 1.0, 0.05, &bar, 1);
  EXPECT_NEAR(swing.height(), 0.12, 1e-12) << "the via point's height above the line";
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
