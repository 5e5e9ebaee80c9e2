#include "marionette/sim/camera_noise.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace marionette::sim {

namespace {

// Standard normal CDF.
double Phi(double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); }

// Phi^-1(p) by bisection on [-9, 9] (monotone, 60 halvings: far below float resolution).
double InverseNormalCdf(double p) {
  double lo = -9.0, hi = 9.0;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (Phi(mid) < p ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// SplitMix64: spreads any seed (0 included) into a non-zero xorshift state.
std::uint64_t SplitMix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

void CheckSigma(const char* what, double sigma) {
  if (!std::isfinite(sigma) || sigma < 0.0) {
    throw std::invalid_argument(std::string("camera noise: ") + what +
                                " must be finite and >= 0, got " + std::to_string(sigma));
  }
}

}  // namespace

CameraNoise::CameraNoise(const CameraNoiseSettings& settings) : settings_(settings) {
  CheckSigma("grey_sigma", settings.grey_sigma);
  CheckSigma("depth_sigma_m", settings.depth_sigma_m);
  if (!enabled()) return;  // Apply() draws nothing: no table (~0.1 s) for a noise-free camera
  const double n = static_cast<double>(quantiles_.size());
  for (std::size_t k = 0; k < quantiles_.size(); ++k) {
    quantiles_[k] = static_cast<float>(InverseNormalCdf((static_cast<double>(k) + 0.5) / n));
  }
  state_ = SplitMix64(settings.seed);
  if (state_ == 0) state_ = 0x9E3779B97F4A7C15ull;
}

float CameraNoise::StandardNormal() {
  if (bits_left_ == 0) {
    // xorshift64* (Vigna): full period, the multiply fixes the low bits' weakness.
    state_ ^= state_ >> 12;
    state_ ^= state_ << 25;
    state_ ^= state_ >> 27;
    bits_ = state_ * 0x2545F4914F6CDD1Dull;
    bits_left_ = 4;
  }
  const float z = quantiles_[bits_ & 0xFFFF];
  bits_ >>= 16;
  --bits_left_;
  return z;
}

void CameraNoise::Apply(RgbdFrame* frame) {
  if (settings_.grey_sigma > 0.0) {
    const float sigma = static_cast<float>(settings_.grey_sigma);
    std::uint8_t* p = frame->rgb.data();
    for (std::size_t i = 0; i + 2 < frame->rgb.size(); i += 3) {
      const float n = sigma * StandardNormal();
      for (int c = 0; c < 3; ++c) {
        p[i + c] = static_cast<std::uint8_t>(std::clamp(std::lround(p[i + c] + n), 0L, 255L));
      }
    }
  }
  if (settings_.depth_sigma_m > 0.0) {
    const float sigma = static_cast<float>(settings_.depth_sigma_m);
    for (float& z : frame->depth) {
      if (z > 0.0f) z = std::max(z + sigma * StandardNormal(), 1e-4f);  // a return stays a return
    }
  }
}

}  // namespace marionette::sim
