// The measured ZMP against its definition: point forces on the ground under two soles, each
// sole's wrench taken about its origin at some height above the ground (a force-torque sensor
// in the ankle), give back the forces' centre of pressure on the ground.
#include <gtest/gtest.h>

#include <array>
#include <random>

#include "marionette/walk/support_polygon.h"

namespace marionette::walk {
namespace {

TEST(MeasuredZmpTest, IsTheCentreOfPressureWhateverTheSensorsHeightAndShearForces) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const double ground = 0.05;
  for (int trial = 0; trial < 200; ++trial) {
    std::array<SoleWrench, 2> w;
    double fz = 0.0, px = 0.0, py = 0.0;
    for (int s = 0; s < 2; ++s) {
      w[s].origin << u(rng), u(rng), ground + (trial % 3) * 0.05 + 0.1 * std::abs(u(rng));
      for (int k = 0; k < 4; ++k) {  // contact points under the sole, on the ground
        const Eigen::Vector3d p(w[s].origin.x() + 0.1 * u(rng), w[s].origin.y() + 0.06 * u(rng),
                                ground);
        const Eigen::Vector3d f(60.0 * u(rng), 60.0 * u(rng), 100.0 + 90.0 * u(rng));
        w[s].force += f;
        w[s].torque += (p - w[s].origin).cross(f);
        fz += f.z(), px += p.x() * f.z(), py += p.y() * f.z();
      }
    }
    Eigen::Vector2d zmp;
    ASSERT_TRUE(MeasuredZmp(w.data(), 2, ground, &zmp, 1.0));
    EXPECT_LT((zmp - Eigen::Vector2d(px / fz, py / fz)).norm(), 1e-12) << trial;
  }
}

TEST(MeasuredZmpTest, SolesWithoutLoadAreLeftOut) {
  std::array<SoleWrench, 2> w;
  w[0].origin << 0.2, 0.1, 0.0;
  w[0].force << 0.0, 0.0, 500.0;
  w[1].origin << 5.0, 5.0, 0.0;
  w[1].force << 0.0, 0.0, 5.0;  // below the default 10 N
  w[1].torque << 3.0, -3.0, 0.0;
  Eigen::Vector2d zmp(9.0, 9.0);
  ASSERT_TRUE(MeasuredZmp(w.data(), 2, 0.0, &zmp));
  EXPECT_LT((zmp - Eigen::Vector2d(0.2, 0.1)).norm(), 1e-15);
  w[0].force.z() = 0.0;
  EXPECT_FALSE(MeasuredZmp(w.data(), 2, 0.0, &zmp));
  EXPECT_LT((zmp - Eigen::Vector2d(0.2, 0.1)).norm(), 1e-15) << "left untouched";
}

}  // namespace
}  // namespace marionette::walk
