#include "marionette/perception/apriltag_detector.h"

#include <visp3/core/vpException.h>
#include <visp3/core/vpImage.h>
#include <visp3/detection/vpDetectorAprilTag.h>

#include <cmath>
#include <utility>

#include "marionette/perception/planar_pose.h"
#include "visp_conversions.h"

namespace marionette::perception {

using internal::AllFinite;
using internal::FromVisp;
using internal::ToVisp;

std::array<Eigen::Vector3d, 4> TagCorners(double tag_size) {
  const double h = 0.5 * tag_size;
  // ViSP places the corners at (-h, h), (h, h), (h, -h), (-h, -h) in a z-into-the-tag frame and
  // then turns it half a turn about x (setZAlignedWithCameraAxis(false)): y and z flip.
  return {Eigen::Vector3d(-h, -h, 0.0), Eigen::Vector3d(h, -h, 0.0), Eigen::Vector3d(h, h, 0.0),
          Eigen::Vector3d(-h, h, 0.0)};
}

class AprilTagDetector::Impl {
 public:
  explicit Impl(const AprilTagDetectorOptions& o)
      : detector(vpDetectorAprilTag::TAG_36h11, vpDetectorAprilTag::HOMOGRAPHY_VIRTUAL_VS) {
    detector.setAprilTagQuadDecimate(o.quad_decimate);
    detector.setAprilTagQuadSigma(o.quad_sigma);
    detector.setAprilTagNbThreads(o.num_threads);
    detector.setAprilTagRefineEdges(o.refine_edges);
    detector.setAprilTagDecodeSharpening(o.decode_sharpening);
    detector.setZAlignedWithCameraAxis(false);
  }
  vpDetectorAprilTag detector;
};

AprilTagDetector::AprilTagDetector(const AprilTagDetectorOptions& options) {
  if (!(options.quad_decimate >= 1.0f) || !(options.quad_sigma >= 0.0f) ||
      options.num_threads < 1 || !(options.decode_sharpening >= 0.0)) {
    throw PerceptionError(
        "AprilTagDetector: need quad_decimate >= 1, quad_sigma >= 0, num_threads >= 1, "
        "decode_sharpening >= 0");
  }
  impl_ = std::make_unique<Impl>(options);
}

AprilTagDetector::~AprilTagDetector() = default;

std::vector<TagDetection> AprilTagDetector::Detect(const std::uint8_t* gray, int width, int height,
                                                   const CameraIntrinsics& intrinsics,
                                                   const TagSizes& sizes) {
  if (gray == nullptr) throw PerceptionError("AprilTagDetector::Detect: image is null");
  intrinsics.Validate();
  if (width != intrinsics.width || height != intrinsics.height) {
    throw PerceptionError("AprilTagDetector::Detect: image is " + std::to_string(width) + " x " +
                          std::to_string(height) + " but the intrinsics are for " +
                          std::to_string(intrinsics.width) + " x " +
                          std::to_string(intrinsics.height));
  }
  // Wraps the caller's buffer without copying (ViSP only reads it).
  vpImage<unsigned char> image(const_cast<unsigned char*>(gray), static_cast<unsigned>(height),
                               static_cast<unsigned>(width), /*copyData=*/false);
  vpDetectorAprilTag& det = impl_->detector;
  det.detect(image);
  const std::vector<int> ids = det.getTagsId();
  const std::vector<std::vector<vpImagePoint>> polygons = det.getTagsCorners();
  // AprilTag puts pixel centres at (0.5, 0.5) (AprilRobotics/apriltag#121); our intrinsics put
  // them at integers. ViSP gets the principal point in AprilTag's convention, callers get
  // corners in ours.
  CameraIntrinsics apriltag_intrinsics = intrinsics;
  apriltag_intrinsics.cx += 0.5;
  apriltag_intrinsics.cy += 0.5;
  const vpCameraParameters cam = ToVisp(apriltag_intrinsics);

  std::vector<TagDetection> out(ids.size());
  for (size_t i = 0; i < ids.size(); ++i) {
    TagDetection& d = out[i];
    d.id = ids[i];
    for (int c = 0; c < 4; ++c) {
      d.corners[c] = {polygons[i][c].get_u() - 0.5, polygons[i][c].get_v() - 0.5};
    }
    const double size = sizes.SizeOf(d.id);
    if (!(size > 0.0) || !std::isfinite(size)) continue;
    d.tag_size = size;

    // The second hypothesis is left untouched when AprilTag's solver finds no other minimum:
    // start it behind the camera to recognise that case.
    vpHomogeneousMatrix cMo1, cMo2;
    cMo2[2][3] = -1.0;
    try {
      if (!det.getPose(i, size, cam, cMo1, &cMo2) || !AllFinite(cMo1)) continue;
    } catch (const vpException&) {
      continue;
    }
    const std::array<Eigen::Vector3d, 4> model = TagCorners(size);
    const std::vector<Eigen::Vector3d> p_T(model.begin(), model.end());
    const std::vector<Eigen::Vector2d> uv(d.corners.begin(), d.corners.end());

    // Both hypotheses as local minima of the same pixel residual: ViSP refines the first by
    // virtual visual servoing; the second comes from AprilTag's orthogonal iteration, refine it
    // too.
    PoseHypothesis h1{FromVisp(cMo1), 0.0};
    h1.reprojection_error = ReprojectionError(p_T, uv, intrinsics, h1.X_CT);
    d.has_pose = std::isfinite(h1.reprojection_error);
    if (!d.has_pose) continue;
    PoseHypothesis h2 = h1;
    if (AllFinite(cMo2) && cMo2[2][3] > 0.0) {
      const PoseEstimate refined = RefinePose(p_T, uv, intrinsics, FromVisp(cMo2));
      if (refined.ok) {
        const double angle =
            Eigen::AngleAxisd(h1.X_CT.linear().transpose() * refined.X_CO.linear()).angle();
        // The same minimum reached twice is not a second hypothesis.
        if (angle > 1e-3) {
          h2 = {refined.X_CO, refined.reprojection_error};
          d.has_second = true;
        }
      }
    }
    if (h2.reprojection_error < h1.reprojection_error) std::swap(h1, h2);
    d.hypotheses = {h1, h2};
  }
  return out;
}

}  // namespace marionette::perception
