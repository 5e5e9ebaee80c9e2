#pragma once
// Sensor noise of the simulated head camera: the rendered frames are exact, a real RGB-D sensor's
// are not (read noise on the image, noise on the depth). Applied by the controller's camera thread
// to every frame it publishes (--camera-noise, --depth-noise) and by tests.

#include <array>
#include <cstdint>

#include "marionette/sim/rgbd_renderer.h"

namespace marionette::sim {

struct CameraNoiseSettings {
  double grey_sigma =
      0.0;  ///< [grey levels] luminance noise: the same draw on R, G and B of a pixel,
            ///< so the grey image a tag detector reads gets exactly this sigma
  double depth_sigma_m = 0.0;  ///< [m] on every pixel that has a depth (0 = no return stays 0)
  std::uint64_t seed = 0;
};

/// I.i.d. zero-mean Gaussian noise per pixel, drawn from a 65536-entry inverse-CDF table indexed by
/// a 64-bit xorshift generator (four draws per step); the tails are cut at 4.17 sigma (the table's
/// last quantile). Colours are rounded and clamped to [0, 255]. A 640 x 480 RGB-D frame takes ~4 ms
/// in the camera thread (the table, ~0.1 s, is built once, only when a sigma is > 0). No allocation
/// after construction.
class CameraNoise {
 public:
  /// Throws std::invalid_argument when a sigma is negative or not finite.
  explicit CameraNoise(const CameraNoiseSettings& settings);

  bool enabled() const { return settings_.grey_sigma > 0.0 || settings_.depth_sigma_m > 0.0; }

  /// Adds the noise to `frame` in place: rgb (height*width*3), depth (height*width) [m]; either
  /// may be empty.
  void Apply(RgbdFrame* frame);

 private:
  float StandardNormal();

  CameraNoiseSettings settings_;
  std::array<float, 65536> quantiles_{};  // Phi^-1((k + 0.5) / 65536)
  std::uint64_t state_ = 0;
  std::uint64_t bits_ = 0;  // the current draw's unused 16-bit indices
  int bits_left_ = 0;
};

}  // namespace marionette::sim
