#pragma once
// Hand-eye calibration (Tsai-Lenz, as in thesis 001 §4.3, through ViSP's vpHandEyeCalibration).

#include <Eigen/Geometry>
#include <vector>

namespace marionette::perception {

/// Result of a hand-eye calibration.
struct HandEyeResult {
  Eigen::Isometry3d X_EC = Eigen::Isometry3d::Identity();  // effector <- camera
  Eigen::Isometry3d X_RT = Eigen::Isometry3d::Identity();  // robot base <- target (mean)
  double rms_position = 0.0;  // [m] spread of X_RE_i X_EC X_CT_i around X_RT
  double rms_rotation = 0.0;  // [rad]
};

/// Eye-in-hand: a camera C rigidly mounted on an effector E observes a target T fixed relative
/// to the base R. From pairs (X_RE_i by kinematics, X_CT_i by vision), finds X_EC such that
/// X_RE_i X_EC X_CT_i is the same X_RT for all i (AX = XB with A = X_RE_i^-1 X_RE_j,
/// B = X_CT_i X_CT_j^-1). Tsai-Lenz closed form refined by ViSP's non-linear least squares.
/// Needs >= 3 pairs with non-parallel rotation axes; throws PerceptionError otherwise.
HandEyeResult CalibrateHandEye(const std::vector<Eigen::Isometry3d>& X_RE,
                               const std::vector<Eigen::Isometry3d>& X_CT);

}  // namespace marionette::perception
