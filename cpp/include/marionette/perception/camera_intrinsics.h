#pragma once
// Pinhole camera intrinsics shared by the perception library (no ViSP types in this header).

#include <Eigen/Core>
#include <stdexcept>
#include <string>

namespace marionette::perception {

/// Bad input to a perception function (image size, intrinsics, points): the message says which.
class PerceptionError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// Pinhole intrinsics without distortion, pixel centres at integer coordinates: the point
/// p_C = (x, y, z) of the optical frame (x right, y down, z forward) projects to
/// u = fx x / z + cx, v = fy y / z + cy (u: column, v: row, top-left pixel at (0, 0)).
struct CameraIntrinsics {
  int width = 0;    // [px]
  int height = 0;   // [px]
  double fx = 0.0;  // [px]
  double fy = 0.0;  // [px]
  double cx = 0.0;  // [px]
  double cy = 0.0;  // [px]

  /// Throws PerceptionError unless sizes are positive and fx, fy > 0, cx, cy finite.
  void Validate() const;
  /// Pixel (u, v) of a point in front of the camera (z > 0).
  Eigen::Vector2d Project(const Eigen::Vector3d& p_C) const {
    return {fx * p_C.x() / p_C.z() + cx, fy * p_C.y() / p_C.z() + cy};
  }
};

}  // namespace marionette::perception
