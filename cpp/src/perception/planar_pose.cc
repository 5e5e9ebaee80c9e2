#include "marionette/perception/planar_pose.h"

#include <visp3/core/vpException.h>
#include <visp3/core/vpImage.h>
#include <visp3/core/vpImagePoint.h>
#include <visp3/core/vpPoint.h>
#include <visp3/vision/vpPose.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "visp_conversions.h"

namespace marionette::perception {

using internal::AllFinite;
using internal::FromVisp;
using internal::ToVisp;

namespace {

void CheckPoints(const char* who, const std::vector<Eigen::Vector3d>& p_O,
                 const std::vector<Eigen::Vector2d>& uv) {
  if (p_O.size() != uv.size()) {
    throw PerceptionError(std::string(who) + ": " + std::to_string(p_O.size()) +
                          " model points but " + std::to_string(uv.size()) + " image points");
  }
  for (size_t i = 0; i < p_O.size(); ++i) {
    if (!p_O[i].allFinite() || !uv[i].allFinite()) {
      throw PerceptionError(std::string(who) + ": point " + std::to_string(i) + " is not finite");
    }
  }
}

// ViSP's pose works on normalised coordinates x = (u - cx) / fx, y = (v - cy) / fy.
vpPoint MakePoint(const Eigen::Vector3d& p_O, const Eigen::Vector2d& uv,
                  const CameraIntrinsics& k) {
  vpPoint pt;
  pt.setWorldCoordinates(p_O.x(), p_O.y(), p_O.z());
  pt.set_x((uv.x() - k.cx) / k.fx);
  pt.set_y((uv.y() - k.cy) / k.fy);
  return pt;
}

}  // namespace

double ReprojectionError(const std::vector<Eigen::Vector3d>& p_O,
                         const std::vector<Eigen::Vector2d>& uv, const CameraIntrinsics& intrinsics,
                         const Eigen::Isometry3d& X_CO) {
  CheckPoints("ReprojectionError", p_O, uv);
  double sum = 0.0;
  for (size_t i = 0; i < p_O.size(); ++i) {
    const Eigen::Vector3d p_C = X_CO * p_O[i];
    if (p_C.z() <= 0.0) return std::numeric_limits<double>::infinity();
    sum += (intrinsics.Project(p_C) - uv[i]).squaredNorm();
  }
  return sum;
}

PoseEstimate RefinePose(const std::vector<Eigen::Vector3d>& p_O,
                        const std::vector<Eigen::Vector2d>& uv, const CameraIntrinsics& intrinsics,
                        const Eigen::Isometry3d& X_CO_initial) {
  intrinsics.Validate();
  CheckPoints("RefinePose", p_O, uv);
  if (p_O.size() < 4) {
    throw PerceptionError("RefinePose: needs at least 4 points, got " + std::to_string(p_O.size()));
  }
  if (!X_CO_initial.matrix().allFinite()) {
    throw PerceptionError("RefinePose: the initial pose is not finite");
  }
  vpPose pose;
  for (size_t i = 0; i < p_O.size(); ++i) pose.addPoint(MakePoint(p_O[i], uv[i], intrinsics));
  vpHomogeneousMatrix cMo = ToVisp(X_CO_initial);
  PoseEstimate out;
  out.num_points = static_cast<int>(p_O.size());
  try {
    out.ok = pose.computePose(vpPose::VIRTUAL_VS, cMo) && AllFinite(cMo);
  } catch (const vpException&) {
    out.ok = false;  // singular interaction matrix: degenerate points
  }
  if (out.ok) {
    out.X_CO = FromVisp(cMo);
    out.reprojection_error = ReprojectionError(p_O, uv, intrinsics, out.X_CO);
    out.ok = std::isfinite(out.reprojection_error);
  }
  return out;
}

PoseEstimate PoseFromRgbd(const float* depth, const CameraIntrinsics& intrinsics,
                          const std::vector<Eigen::Vector2d>& corners,
                          const std::vector<Eigen::Vector3d>& p_O) {
  intrinsics.Validate();
  if (depth == nullptr) throw PerceptionError("PoseFromRgbd: depth is null");
  CheckPoints("PoseFromRgbd", p_O, corners);
  if (p_O.size() < 4) {
    throw PerceptionError("PoseFromRgbd: needs at least 4 corners, got " +
                          std::to_string(p_O.size()));
  }
  // ViSP skips depth <= 0; NaN or infinite returns would poison its plane fit.
  vpImage<float> depth_map(static_cast<unsigned>(intrinsics.height),
                           static_cast<unsigned>(intrinsics.width));
  const size_t n = static_cast<size_t>(intrinsics.width) * intrinsics.height;
  for (size_t i = 0; i < n; ++i) {
    const float z = depth[i];
    depth_map.bitmap[i] = std::isfinite(z) && z > 0.0f ? z : 0.0f;
  }
  std::vector<vpImagePoint> image_points;
  std::vector<vpPoint> model_points;
  for (size_t i = 0; i < p_O.size(); ++i) {
    image_points.emplace_back(corners[i].y(), corners[i].x());  // vpImagePoint(i = v, j = u)
    vpPoint pt;
    pt.setWorldCoordinates(p_O[i].x(), p_O[i].y(), p_O[i].z());
    model_points.push_back(pt);
  }
  PoseEstimate out;
  out.num_points = static_cast<int>(p_O.size());
  vpHomogeneousMatrix cMo;
  try {
    out.ok = vpPose::computePlanarObjectPoseFromRGBD(depth_map, image_points, ToVisp(intrinsics),
                                                     model_points, cMo, &out.confidence) &&
             AllFinite(cMo);
  } catch (const vpException&) {
    out.ok = false;
  }
  if (out.ok) {
    out.X_CO = FromVisp(cMo);
    out.reprojection_error = ReprojectionError(p_O, corners, intrinsics, out.X_CO);
    out.ok = std::isfinite(out.reprojection_error);
  }
  return out;
}

namespace {

// A depth pixel: its ray (x, y, 1) in the camera frame and its depth z [m].
struct DepthPixel {
  Eigen::Vector3d ray;
  double z;
};

constexpr double kMinIncidence = 0.1;      // |n . ray| below: a ray grazing the plane (> 84 deg)
constexpr size_t kMinPixelsForSigma = 30;  // fewer depth pixels: the assumed sigma is kept
constexpr double kMinDepthSigma = 1e-4;    // [m]: a noise-free depth still has its rounding

// Even-odd rule point-in-polygon test.
bool InsidePolygon(const std::vector<Eigen::Vector2d>& poly, double u, double v) {
  bool inside = false;
  for (size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const Eigen::Vector2d& a = poly[i];
    const Eigen::Vector2d& b = poly[j];
    if ((a.y() > v) != (b.y() > v) && u < (b.x() - a.x()) * (v - a.y()) / (b.y() - a.y()) + a.x()) {
      inside = !inside;
    }
  }
  return inside;
}

Eigen::Matrix3d Skew(const Eigen::Vector3d& w) {
  Eigen::Matrix3d S;
  S << 0, -w.z(), w.y(), w.z(), 0, -w.x(), -w.y(), w.x(), 0;
  return S;
}

// exp of a twist (v, w) as a rigid transform (Rodrigues + left Jacobian for the translation).
Eigen::Isometry3d ExpSE3(const Eigen::Matrix<double, 6, 1>& d) {
  const Eigen::Vector3d v = d.head<3>(), w = d.tail<3>();
  const double th = w.norm();
  const Eigen::Matrix3d W = Skew(w);
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity(), V = Eigen::Matrix3d::Identity();
  if (th > 1e-10) {
    R += std::sin(th) / th * W + (1 - std::cos(th)) / (th * th) * W * W;
    V += (1 - std::cos(th)) / (th * th) * W + (th - std::sin(th)) / (th * th * th) * W * W;
  } else {
    R += W;
    V += 0.5 * W;
  }
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = R;
  X.translation() = V * v;
  return X;
}

}  // namespace

PoseEstimate RefinePoseRgbd(const std::vector<Eigen::Vector3d>& p_O,
                            const std::vector<Eigen::Vector2d>& uv,
                            const std::vector<DepthPlane>& planes, const float* depth,
                            const CameraIntrinsics& k, const Eigen::Isometry3d& X_CO_initial,
                            const RgbdRefineOptions& options) {
  k.Validate();
  CheckPoints("RefinePoseRgbd", p_O, uv);
  if (depth == nullptr) throw PerceptionError("RefinePoseRgbd: depth is null");
  if (!(options.sigma_pixel > 0.0 && options.sigma_depth > 0.0 && options.polygon_scale > 0.0 &&
        options.polygon_scale <= 2.0 && options.max_iterations > 0)) {
    throw PerceptionError(
        "RefinePoseRgbd: need sigma_pixel > 0, sigma_depth > 0, 0 < polygon_scale <= 2, "
        "max_iterations > 0");
  }
  if (!X_CO_initial.matrix().allFinite()) {
    throw PerceptionError("RefinePoseRgbd: the initial pose is not finite");
  }
  // Depth pixels of each plane, inside its shrunk polygon: their ray a_j = (x, y, 1) and depth z_j.
  std::vector<std::vector<DepthPixel>> pixels(planes.size());
  size_t num_depth = 0;
  for (size_t p = 0; p < planes.size(); ++p) {
    const auto& poly = planes[p].polygon;
    if (poly.size() < 3 || !std::isfinite(planes[p].offset_O) ||
        !(std::abs(planes[p].normal_O.norm() - 1.0) < 1e-6)) {
      throw PerceptionError("RefinePoseRgbd: plane " + std::to_string(p) +
                            " needs >= 3 polygon corners and a unit normal");
    }
    Eigen::Vector2d centroid = Eigen::Vector2d::Zero();
    for (const auto& c : poly) centroid += c;
    centroid /= static_cast<double>(poly.size());
    std::vector<Eigen::Vector2d> shrunk;
    double u0 = k.width, u1 = 0.0, v0 = k.height, v1 = 0.0;
    for (const auto& c : poly) {
      shrunk.push_back(centroid + options.polygon_scale * (c - centroid));
      u0 = std::min(u0, shrunk.back().x());
      u1 = std::max(u1, shrunk.back().x());
      v0 = std::min(v0, shrunk.back().y());
      v1 = std::max(v1, shrunk.back().y());
    }
    const int ua = std::max(0, static_cast<int>(std::floor(u0)));
    const int ub = std::min(k.width - 1, static_cast<int>(std::ceil(u1)));
    const int va = std::max(0, static_cast<int>(std::floor(v0)));
    const int vb = std::min(k.height - 1, static_cast<int>(std::ceil(v1)));
    for (int v = va; v <= vb; ++v) {
      for (int u = ua; u <= ub; ++u) {
        const float z = depth[static_cast<size_t>(v) * k.width + u];
        if (!(std::isfinite(z) && z > 0.0f) || !InsidePolygon(shrunk, u, v)) continue;
        pixels[p].push_back({Eigen::Vector3d((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0), z});
      }
    }
    num_depth += pixels[p].size();
  }
  PoseEstimate out;
  out.num_points = static_cast<int>(p_O.size() + num_depth);
  if (num_depth == 0) return out;

  // Gauss-Newton at a given depth sigma, from X; false if the estimate left the camera's front.
  const double wp = 1.0 / options.sigma_pixel;
  std::vector<double> residuals;
  residuals.reserve(num_depth);
  Eigen::Isometry3d X = X_CO_initial;
  auto solve = [&](double sigma_depth) {
    const double wd = 1.0 / sigma_depth;
    const double huber = 3.0 * sigma_depth;  // beyond 3 sigma, residuals count linearly
    for (int it = 0; it < options.max_iterations; ++it) {
      Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
      for (size_t i = 0; i < p_O.size(); ++i) {
        const Eigen::Vector3d pc = X * p_O[i];
        if (pc.z() <= 1e-9) return false;  // the estimate went behind the camera
        const double iz = 1.0 / pc.z();
        Eigen::Matrix<double, 2, 3> Jpi;
        Jpi << k.fx * iz, 0, -k.fx * pc.x() * iz * iz, 0, k.fy * iz, -k.fy * pc.y() * iz * iz;
        Eigen::Matrix<double, 3, 6> Jp;
        Jp << Eigen::Matrix3d::Identity(), -Skew(pc);  // d(exp(d) p)/dd at 0
        const Eigen::Matrix<double, 2, 6> J = wp * Jpi * Jp;
        const Eigen::Vector2d r = wp * (k.Project(pc) - uv[i]);
        H += J.transpose() * J;
        g += J.transpose() * r;
      }
      residuals.clear();
      for (size_t p = 0; p < planes.size(); ++p) {
        const Eigen::Vector3d n = X.linear() * planes[p].normal_O;
        const double d = planes[p].offset_O + n.dot(X.translation());  // plane n . p_C = d
        for (const DepthPixel& px : pixels[p]) {
          const double s = n.dot(px.ray);
          if (std::abs(s) < kMinIncidence || !(d / s > 0.0)) continue;  // grazing, or behind
          const double r = d / s - px.z;
          residuals.push_back(r);
          const double w = std::abs(r) <= huber ? 1.0 : huber / std::abs(r);  // IRLS Huber
          Eigen::Matrix<double, 1, 6> J;
          J << n.transpose() / s, -(d / (s * s)) * n.cross(px.ray).transpose();
          H += (w * wd * wd) * J.transpose() * J;
          g += (w * wd * wd * r) * J.transpose();
        }
      }
      const Eigen::Matrix<double, 6, 1> step = -H.ldlt().solve(g);
      if (!step.allFinite()) return false;
      X = ExpSE3(step) * X;
      if (step.norm() < 1e-10) break;
    }
    return true;
  };
  // The depth noise the residuals show (1.4826 x their median absolute value, a Gaussian's sigma
  // robust to the Huber tail), re-weighted until it agrees with the one solved with to 10 %: a
  // sigma assumed below the sensor's makes a few hundred pixels outweigh the corners.
  double sigma = options.sigma_depth;
  for (int round = 0; round < 4; ++round) {
    if (!solve(sigma)) return out;
    if (residuals.size() < kMinPixelsForSigma) break;
    std::vector<double> a(residuals.size());
    for (size_t j = 0; j < a.size(); ++j) a[j] = std::abs(residuals[j]);
    std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
    const double measured = std::max(1.4826 * a[a.size() / 2], kMinDepthSigma);
    const bool agrees = std::abs(measured - sigma) <= 0.1 * sigma;
    sigma = measured;
    if (agrees) break;
  }
  out.depth_sigma = sigma;
  out.ok = X.matrix().allFinite();
  out.X_CO = X;
  if (out.ok) {
    out.X_CO.linear() = Eigen::Quaterniond(X.linear()).normalized().toRotationMatrix();
    out.reprojection_error = ReprojectionError(p_O, uv, k, out.X_CO);
    out.ok = std::isfinite(out.reprojection_error);
  }
  return out;
}

}  // namespace marionette::perception
