#pragma once
// Pose of a rigid set of 3D points (the corners of one or several tags of an object) from their
// image projections, optionally with an aligned depth map (thesis 000 §5.2.1: depth resolves the
// planar ambiguity; several tags per object survive occlusions).

#include <Eigen/Geometry>
#include <vector>

#include "marionette/perception/camera_intrinsics.h"

namespace marionette::perception {

/// A pose estimate of frame O in the camera and how well it explains the measurements.
struct PoseEstimate {
  bool ok = false;
  Eigen::Isometry3d X_CO = Eigen::Isometry3d::Identity();
  double reprojection_error = 0.0;  // sum of squared pixel distances over all points [px^2]
  int num_points = 0;
  double confidence = 0.0;   // RGB-D only: ViSP's index in [0, 1] (depth coverage x plane fit)
  double depth_sigma = 0.0;  // RefinePoseRgbd: the depth noise it weighted with [m] (0: none)
};

/// Sum of squared pixel distances between `uv` (n x 2) and the projections of `p_O` (n x 3)
/// through X_CO; +inf when a point is behind the camera.
double ReprojectionError(const std::vector<Eigen::Vector3d>& p_O,
                         const std::vector<Eigen::Vector2d>& uv, const CameraIntrinsics& intrinsics,
                         const Eigen::Isometry3d& X_CO);

/// Minimises the reprojection error of all points over X_CO (ViSP virtual visual servoing, a
/// Gauss-Newton on SE(3)) starting from `X_CO_initial`, which selects the local minimum.
/// Needs >= 4 points (3 in general position are ambiguous); throws PerceptionError otherwise.
PoseEstimate RefinePose(const std::vector<Eigen::Vector3d>& p_O,
                        const std::vector<Eigen::Vector2d>& uv, const CameraIntrinsics& intrinsics,
                        const Eigen::Isometry3d& X_CO_initial);

/// ViSP's vpPose::computePlanarObjectPoseFromRGBD on one planar set of points (one tag): fits a
/// plane (Tukey M-estimator) to the depth pixels inside the corner polygon, intersects the corner
/// rays with it, aligns the model points to those 3D points, then refines on the image corners.
/// The depth plane fixes the tilt that the image alone leaves ambiguous (thesis 000 §5.2.1).
/// depth: (height x width) metric depth along z [m], row-major; <= 0 or NaN = no measurement.
/// `ok` is false when fewer than 5 depth pixels fall inside the polygon.
PoseEstimate PoseFromRgbd(const float* depth, const CameraIntrinsics& intrinsics,
                          const std::vector<Eigen::Vector2d>& corners,
                          const std::vector<Eigen::Vector3d>& p_O);

/// A planar face of the object seen in the depth map: the pixels inside `polygon` (its image
/// corners, >= 3) measure the plane {p_O : normal_O . p_O = offset_O} of frame O.
struct DepthPlane {
  std::vector<Eigen::Vector2d> polygon;  // (u, v) [px]
  Eigen::Vector3d normal_O = Eigen::Vector3d::UnitZ();
  double offset_O = 0.0;  // [m]
};

/// Weights of RefinePoseRgbd's two kinds of residuals.
struct RgbdRefineOptions {
  double sigma_pixel = 0.3;    // corner noise [px]
  double sigma_depth = 0.003;  // depth noise [m] assumed until the depth residuals measure it
  double polygon_scale = 0.8;  // depth pixels are taken in the polygon scaled by this about its
                               // centroid: < 1 keeps away from edges, where depth mixes two
                               // surfaces; a tag's white border allows up to 1.25 (10/8 cells)
  int max_iterations = 20;
};

/// Depth-fused pose: Gauss-Newton on SE(3) (left increments X <- exp(d) X, d = (v, w) in C) of
///   sum_i |pi(X p_O,i) - uv_i|^2 / sigma_pixel^2 + sum_j huber(d_C / (n_C . a_j) - z_j)^2 /
///   sigma_depth^2
/// with a_j = (x_j, y_j, 1) the ray of each depth pixel of a plane, z_j its depth, and the plane
/// n_C . p = d_C in the camera (n_C = R normal_O, d_C = offset_O + n_C . t): the depth the plane
/// predicts along the ray minus the measured one, the direction a depth sensor errs in. Its
/// derivatives: n_C^T / s (v) and -(d_C / s^2) (n_C x a_j)^T (w), s = n_C . a_j. (A point-to-plane
/// distance n_C . (q_j - t) - offset_O, with q_j = z_j a_j, is biased: noise along the rays of a
/// tilted plane tilts its least-squares fit toward them, 1.8 deg for a 4 cm tag at 0.8 m, 30 deg,
/// 3 mm.) A small far tag's tilt, which its corners barely constrain (thesis fig. 5.1), is then
/// fixed by hundreds of depth points while the corners keep the in-plane pose.
/// sigma_depth is what the depth residuals show once solved (1.4826 x their median absolute
/// value, >= 0.1 mm, with >= 30 pixels), re-solved until the two agree to 10 %; options'
/// sigma_depth is the first guess; `depth_sigma` returns the one used. `depth`: (height x width)
/// [m], <= 0 or NaN = none. `num_points` counts corners plus depth pixels used; `ok` is false
/// without any depth pixel.
PoseEstimate RefinePoseRgbd(const std::vector<Eigen::Vector3d>& p_O,
                            const std::vector<Eigen::Vector2d>& uv,
                            const std::vector<DepthPlane>& planes, const float* depth,
                            const CameraIntrinsics& intrinsics,
                            const Eigen::Isometry3d& X_CO_initial,
                            const RgbdRefineOptions& options = {});

}  // namespace marionette::perception
