#pragma once
// AprilTag (tag36h11) detection and per-tag pose with both planar hypotheses, through ViSP's
// vpDetectorAprilTag (thesis 000 §5.2.1). ViSP stays inside the .cc: this header is Eigen only.

#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <map>
#include <memory>
#include <vector>

#include "marionette/perception/camera_intrinsics.h"

namespace marionette::perception {

/// Tag frame T (ViSP's default, z not aligned with the camera): origin at the tag centre, x to
/// the right and y up when the tag is read upright, z out of the printed face towards the viewer.
/// The black square has edge `tag_size`; its corners in T, in detection order (counter-clockwise
/// seen from the front, starting bottom-left), are
///   (-s/2, -s/2, 0), (s/2, -s/2, 0), (s/2, s/2, 0), (-s/2, s/2, 0), s = tag_size.
std::array<Eigen::Vector3d, 4> TagCorners(double tag_size);

/// One pose of a detected tag and its residual.
struct PoseHypothesis {
  Eigen::Isometry3d X_CT = Eigen::Isometry3d::Identity();  // camera <- tag
  double reprojection_error = 0.0;  // sum over the 4 corners of squared pixel distances [px^2]
};

/// A tag found in an image. A planar square has two poses explaining its corners (the Oberkampf
/// ambiguity, thesis fig. 5.1): `hypotheses[0]` has the smaller residual; `hypotheses[1]` is the
/// other local minimum, or a copy of the first when the solver found none (`has_second` false).
struct TagDetection {
  int id = -1;
  std::array<Eigen::Vector2d, 4> corners;  // (u, v) [px], order of TagCorners()
  double tag_size = 0.0;                   // [m]; 0 when no size is known: no pose
  bool has_pose = false;
  bool has_second = false;
  std::array<PoseHypothesis, 2> hypotheses;
};

/// Sizes of the black squares per tag id [m]; `default_size` for the others (<= 0: no pose).
struct TagSizes {
  double default_size = 0.0;
  std::map<int, double> by_id;
  double SizeOf(int id) const {
    auto it = by_id.find(id);
    return it != by_id.end() ? it->second : default_size;
  }
};

/// AprilTag 3 parameters (see apriltag.h); defaults favour accuracy at 640 x 480.
struct AprilTagDetectorOptions {
  float quad_decimate = 1.0f;  // > 1 detects quads on a subsampled image (faster, less range)
  float quad_sigma = 0.0f;     // Gaussian blur before quad detection [px]
  int num_threads = 1;
  bool refine_edges = true;
  double decode_sharpening = 0.25;
};

/// Detects tag36h11 tags in 8-bit grey images and estimates both pose hypotheses of each.
/// Not thread-safe: one detector per thread.
class AprilTagDetector {
 public:
  explicit AprilTagDetector(const AprilTagDetectorOptions& options = {});
  ~AprilTagDetector();
  AprilTagDetector(const AprilTagDetector&) = delete;
  AprilTagDetector& operator=(const AprilTagDetector&) = delete;

  /// gray: (height x width) row-major, top row first. Poses for tags whose size is known.
  /// Throws PerceptionError on a null image or invalid intrinsics/size mismatch.
  std::vector<TagDetection> Detect(const std::uint8_t* gray, int width, int height,
                                   const CameraIntrinsics& intrinsics, const TagSizes& sizes);

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace marionette::perception
