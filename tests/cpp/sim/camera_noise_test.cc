// CameraNoise: the statistics of what it adds (mean, sigma, independence, the same draw on the
// three channels), what it must leave alone (no-return depth, zero settings), clamping, seeding and
// its refusals.
#include "marionette/sim/camera_noise.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

namespace marionette::sim {
namespace {

constexpr int kPixels = 640 * 480;

RgbdFrame Uniform(std::uint8_t grey, float depth_m) {
  RgbdFrame f;
  f.rgb.assign(3 * kPixels, grey);
  f.depth.assign(kPixels, depth_m);
  return f;
}

TEST(CameraNoise, GreyNoiseHasTheRequestedSigmaAndIsTheSameOnEveryChannel) {
  CameraNoise noise({/*grey_sigma=*/2.0, /*depth_sigma_m=*/0.0, /*seed=*/1});
  RgbdFrame f = Uniform(128, 1.0f);
  noise.Apply(&f);
  double sum = 0.0, sum2 = 0.0, lag = 0.0;
  for (int i = 0; i < kPixels; ++i) {
    ASSERT_EQ(f.rgb[3 * i], f.rgb[3 * i + 1]);
    ASSERT_EQ(f.rgb[3 * i], f.rgb[3 * i + 2]);
    const double e = f.rgb[3 * i] - 128.0;
    sum += e, sum2 += e * e;
    if (i > 0) lag += e * (f.rgb[3 * (i - 1)] - 128.0);
  }
  const double mean = sum / kPixels, var = sum2 / kPixels - mean * mean;
  EXPECT_NEAR(mean, 0.0, 0.02);  // 5 standard errors of the mean (2 / sqrt(307200))
  // Rounding to integers adds 1/12 to the variance (Sheppard): sqrt(4 + 1/12) = 2.021.
  EXPECT_NEAR(std::sqrt(var), std::sqrt(4.0 + 1.0 / 12.0), 0.03);
  EXPECT_NEAR(lag / kPixels / var, 0.0, 0.01);  // neighbouring pixels independent
  for (float z : f.depth) ASSERT_EQ(z, 1.0f);   // no depth noise asked
}

TEST(CameraNoise, DepthNoiseHasTheRequestedSigmaAndNoReturnStaysNoReturn) {
  CameraNoise noise({0.0, /*depth_sigma_m=*/0.003, 2});
  RgbdFrame f = Uniform(77, 1.5f);
  for (int i = 0; i < kPixels; i += 2) f.depth[i] = 0.0f;  // half the pixels hit nothing
  noise.Apply(&f);
  double sum = 0.0, sum2 = 0.0;
  int n = 0;
  for (int i = 0; i < kPixels; ++i) {
    if (i % 2 == 0) {
      ASSERT_EQ(f.depth[i], 0.0f);
      continue;
    }
    const double e = f.depth[i] - 1.5;
    sum += e, sum2 += e * e, ++n;
  }
  EXPECT_NEAR(sum / n, 0.0, 5 * 0.003 / std::sqrt(n));
  EXPECT_NEAR(std::sqrt(sum2 / n), 0.003, 0.003 * 0.01);
  for (std::uint8_t c : f.rgb) ASSERT_EQ(c, 77);  // no grey noise asked
}

TEST(CameraNoise, ColoursAreClampedNotWrapped) {
  CameraNoise noise({50.0, 0.0, 3});
  RgbdFrame white = Uniform(255, 1.0f), black = Uniform(0, 1.0f);
  noise.Apply(&white);
  noise.Apply(&black);
  int white_below = 0, black_above = 0;
  for (std::size_t i = 0; i < white.rgb.size(); ++i) {
    white_below += white.rgb[i] < 255;
    black_above += black.rgb[i] > 0;
    ASSERT_GT(white.rgb[i], 30);  // a wrapped 255 + n would land near 0..200
    ASSERT_LT(black.rgb[i], 225);
  }
  // Half the draws push each one out of range (clamped), the other half inside.
  EXPECT_NEAR(white_below / double(white.rgb.size()), 0.5, 0.01);
  EXPECT_NEAR(black_above / double(black.rgb.size()), 0.5, 0.01);
}

TEST(CameraNoise, ZeroSettingsLeaveTheFrameUntouchedAndSeedsReproduce) {
  CameraNoise off({});
  EXPECT_FALSE(off.enabled());
  RgbdFrame f = Uniform(100, 2.0f), g = f;
  off.Apply(&f);
  EXPECT_EQ(f.rgb, g.rgb);
  EXPECT_EQ(f.depth, g.depth);

  CameraNoise a({2.0, 0.002, 7}), b({2.0, 0.002, 7}), c({2.0, 0.002, 8});
  RgbdFrame fa = g, fb = g, fc = g;
  a.Apply(&fa), b.Apply(&fb), c.Apply(&fc);
  EXPECT_EQ(fa.rgb, fb.rgb);
  EXPECT_EQ(fa.depth, fb.depth);
  EXPECT_NE(fa.rgb, fc.rgb);
  // The next frame draws new noise.
  RgbdFrame fa2 = g;
  a.Apply(&fa2);
  EXPECT_NE(fa.rgb, fa2.rgb);
}

TEST(CameraNoise, RefusesNegativeOrNonFiniteSigmas) {
  EXPECT_THROW(CameraNoise({-1.0, 0.0, 0}), std::invalid_argument);
  EXPECT_THROW(CameraNoise({0.0, std::numeric_limits<double>::quiet_NaN(), 0}),
               std::invalid_argument);
  try {
    CameraNoise({std::numeric_limits<double>::infinity(), 0.0, 0});
    FAIL() << "an infinite sigma was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("grey_sigma"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace marionette::sim
