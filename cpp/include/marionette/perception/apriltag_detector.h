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
  // Blur for quad detection chosen per image from its measured pixel noise (EstimateNoiseSigma),
  // at least `quad_sigma`. Sensor noise makes every 4 x 4 tile pass AprilTag's contrast test and
  // multiplies its segmentation work (~10x at 2 grey levels of noise); a blur that brings the
  // noise under that test removes the work. The caller's image is never modified (at
  // quad_decimate 1 AprilTag blurs the image it segments in place: it gets a copy).
  bool noise_adaptive_blur = true;
};

/// Standard deviation [grey levels] of an image's pixel noise: the median absolute response of
/// Immerkaer's mask [1 -2 1; -2 4 -2; 1 -2 1] (the difference of two Laplacians, blind to planes
/// and nearly blind to straight edges), divided by 0.6745 * 6 (its response to i.i.d. noise of
/// standard deviation s has standard deviation 6 s). The median keeps edges and texture, a
/// minority of pixels, from counting as noise. Every `row_step`-th row is used.
double EstimateNoiseSigma(const std::uint8_t* gray, int width, int height, int stride,
                          int row_step = 2);

/// The blur [px of the image AprilTag segments] that noise_adaptive_blur applies for noise of
/// `noise_sigma` grey levels: none under half a grey level (quantisation), otherwise 0.8 px,
/// AprilTag's smallest kernel (3 taps), which divides i.i.d. noise by ~2.8. Wider blurs would
/// cut the remaining work at strong noise but lose small tags (measured at full resolution,
/// 2-6 grey levels of noise: 18-px tags 10/10 found at 0.8 px, 8-9/10 at 1.0, 0/10 at 1.2;
/// 14-px tags 5-9/10 at 0.8, 9-10/10 unblurred).
float BlurForNoise(double noise_sigma);

/// A rectangle of pixels: columns [u0, u1), rows [v0, v1).
struct PixelBox {
  int u0 = 0, v0 = 0, u1 = 0, v1 = 0;
};

/// What the last Detect call did.
struct DetectionStats {
  double noise_sigma = 0.0;  // estimated pixel noise [grey levels] (largest over the regions)
  float quad_sigma = 0.0f;   // blur applied for quad detection [px] (largest over the regions)
  long pixels_searched = 0;  // pixels handed to AprilTag
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
  /// `regions`: search only these boxes of the image (started on AprilTag's tile grid, clipped
  /// to the image, overlapping ones merged so that a tag is found once); empty: the whole image.
  /// A tag is found only where its white border lies inside a searched box, and then with the
  /// corners and poses of a whole-image search, in the whole image's pixels and camera.
  /// Throws PerceptionError on a null image or invalid intrinsics/size mismatch.
  std::vector<TagDetection> Detect(const std::uint8_t* gray, int width, int height,
                                   const CameraIntrinsics& intrinsics, const TagSizes& sizes,
                                   const std::vector<PixelBox>& regions = {});

  const DetectionStats& last_stats() const { return stats_; }

 private:
  class Impl;
  // Appends the tags found in `box` of the image to `out`.
  void DetectIn(const std::uint8_t* gray, int width, const PixelBox& box,
                const CameraIntrinsics& intrinsics, const TagSizes& sizes,
                std::vector<TagDetection>& out);

  std::unique_ptr<Impl> impl_;
  AprilTagDetectorOptions options_;
  DetectionStats stats_;
};

/// `boxes` with their first column and row moved down to multiples of `align`, clipped to a
/// width x height image, empty ones dropped, intersecting ones replaced by their bounding box
/// until none intersect.
std::vector<PixelBox> MergeBoxes(std::vector<PixelBox> boxes, int width, int height, int align = 1);

}  // namespace marionette::perception
