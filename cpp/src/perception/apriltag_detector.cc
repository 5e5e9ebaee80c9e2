#include "marionette/perception/apriltag_detector.h"

#include <visp3/core/vpException.h>
#include <visp3/core/vpImage.h>
#include <visp3/detection/vpDetectorAprilTag.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
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

double EstimateNoiseSigma(const std::uint8_t* gray, int width, int height, int stride,
                          int row_step) {
  if (gray == nullptr || width < 3 || height < 3) return 0.0;
  row_step = std::max(1, row_step);
  // |response| <= 16 * 255; a histogram gives the median in one pass.
  std::array<long, 16 * 255 + 1> histogram{};
  long count = 0;
  for (int v = 1; v + 1 < height; v += row_step) {
    const std::uint8_t* a = gray + static_cast<long>(v - 1) * stride;
    const std::uint8_t* b = a + stride;
    const std::uint8_t* c = b + stride;
    for (int u = 1; u + 1 < width; ++u) {
      const int r = (a[u - 1] + a[u + 1] + c[u - 1] + c[u + 1]) -
                    2 * (a[u] + c[u] + b[u - 1] + b[u + 1]) + 4 * b[u];
      ++histogram[static_cast<std::size_t>(std::abs(r))];
      ++count;
    }
  }
  long seen = 0;
  for (std::size_t r = 0; r < histogram.size(); ++r) {
    seen += histogram[r];
    if (2 * seen >= count) return static_cast<double>(r) / (0.6745 * 6.0);
  }
  return 0.0;
}

float BlurForNoise(double noise_sigma) {
  constexpr double kNoiseFloor = 0.5;  // [grey levels]: quantisation alone
  constexpr float kBlur = 0.8f;        // [px]: AprilTag's 3-tap kernel (it uses 4 sigma, odd)
  return noise_sigma > kNoiseFloor ? kBlur : 0.0f;
}

std::vector<PixelBox> MergeBoxes(std::vector<PixelBox> boxes, int width, int height, int align) {
  align = std::max(1, align);
  const auto down = [align](int x) { return x >= 0 ? x / align * align : 0; };
  std::vector<PixelBox> out;
  for (PixelBox b : boxes) {
    b.u0 = down(b.u0);
    b.v0 = down(b.v0);
    b.u1 = std::min(b.u1, width);
    b.v1 = std::min(b.v1, height);
    if (b.u1 > b.u0 && b.v1 > b.v0) out.push_back(b);
  }
  const auto intersect = [](const PixelBox& a, const PixelBox& b) {
    return a.u0 < b.u1 && b.u0 < a.u1 && a.v0 < b.v1 && b.v0 < a.v1;
  };
  for (bool merged = true; merged;) {
    merged = false;
    for (std::size_t i = 0; i < out.size() && !merged; ++i) {
      for (std::size_t j = i + 1; j < out.size() && !merged; ++j) {
        if (!intersect(out[i], out[j])) continue;
        out[i] = {std::min(out[i].u0, out[j].u0), std::min(out[i].v0, out[j].v0),
                  std::max(out[i].u1, out[j].u1), std::max(out[i].v1, out[j].v1)};
        out.erase(out.begin() + static_cast<long>(j));
        merged = true;
      }
    }
  }
  return out;
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
  options_ = options;
}

AprilTagDetector::~AprilTagDetector() = default;

std::vector<TagDetection> AprilTagDetector::Detect(const std::uint8_t* gray, int width, int height,
                                                   const CameraIntrinsics& intrinsics,
                                                   const TagSizes& sizes,
                                                   const std::vector<PixelBox>& regions) {
  if (gray == nullptr) throw PerceptionError("AprilTagDetector::Detect: image is null");
  intrinsics.Validate();
  if (width != intrinsics.width || height != intrinsics.height) {
    throw PerceptionError("AprilTagDetector::Detect: image is " + std::to_string(width) + " x " +
                          std::to_string(height) + " but the intrinsics are for " +
                          std::to_string(intrinsics.width) + " x " +
                          std::to_string(intrinsics.height));
  }
  stats_ = {};
  std::vector<TagDetection> out;
  if (regions.empty()) {
    DetectIn(gray, width, {0, 0, width, height}, intrinsics, sizes, out);
  } else {
    // AprilTag thresholds 4 x 4 tiles of the decimated image: boxes start on that grid so
    // that a tag's pixels are segmented as in the whole image.
    const int tile = static_cast<int>(std::ceil(4.0f * options_.quad_decimate));
    for (const PixelBox& box : MergeBoxes(regions, width, height, tile)) {
      DetectIn(gray, width, box, intrinsics, sizes, out);
    }
  }
  return out;
}

void AprilTagDetector::DetectIn(const std::uint8_t* gray, int width, const PixelBox& box,
                                const CameraIntrinsics& intrinsics, const TagSizes& sizes,
                                std::vector<TagDetection>& out) {
  const int w = box.u1 - box.u0, h = box.v1 - box.v0;
  const std::uint8_t* origin = gray + static_cast<long>(box.v0) * width + box.u0;
  float quad_sigma = options_.quad_sigma;
  if (options_.noise_adaptive_blur) {
    const double noise = EstimateNoiseSigma(origin, w, h, width);
    stats_.noise_sigma = std::max(stats_.noise_sigma, noise);
    quad_sigma = std::max(quad_sigma, BlurForNoise(noise));
  }
  stats_.quad_sigma = std::max(stats_.quad_sigma, quad_sigma);
  stats_.pixels_searched += static_cast<long>(w) * h;
  vpDetectorAprilTag& det = impl_->detector;
  det.setAprilTagQuadSigma(quad_sigma);
  // Whole rows are contiguous: ViSP reads the caller's buffer in place, unless AprilTag would
  // blur it there (it blurs the image it segments, which is the caller's at quad_decimate 1). A
  // narrower box is copied.
  vpImage<unsigned char> crop;
  const bool blurs_in_place = quad_sigma > 0.0f && options_.quad_decimate <= 1.0f;
  const bool whole_rows = w == width && !blurs_in_place;
  if (!whole_rows) {
    crop.resize(static_cast<unsigned>(h), static_cast<unsigned>(w));
    for (int v = 0; v < h; ++v) {
      std::memcpy(crop[v], origin + static_cast<long>(v) * width, static_cast<std::size_t>(w));
    }
  }
  vpImage<unsigned char> image(whole_rows ? const_cast<unsigned char*>(origin) : crop.bitmap,
                               static_cast<unsigned>(h), static_cast<unsigned>(w),
                               /*copyData=*/false);
  det.detect(image);
  const std::vector<int> ids = det.getTagsId();
  const std::vector<std::vector<vpImagePoint>> polygons = det.getTagsCorners();
  // AprilTag puts pixel centres at (0.5, 0.5) (AprilRobotics/apriltag#121); our intrinsics put
  // them at integers. ViSP gets the principal point in AprilTag's convention and in the box's
  // pixels, callers get corners in ours and in the whole image's.
  CameraIntrinsics apriltag_intrinsics = intrinsics;
  apriltag_intrinsics.cx += 0.5 - box.u0;
  apriltag_intrinsics.cy += 0.5 - box.v0;
  const vpCameraParameters cam = ToVisp(apriltag_intrinsics);

  for (size_t i = 0; i < ids.size(); ++i) {
    TagDetection& d = out.emplace_back();
    d.id = ids[i];
    for (int c = 0; c < 4; ++c) {
      d.corners[c] = {polygons[i][c].get_u() - 0.5 + box.u0, polygons[i][c].get_v() - 0.5 + box.v0};
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
}

}  // namespace marionette::perception
