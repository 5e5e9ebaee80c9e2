#include "marionette/perception/hand_eye.h"

#include <visp3/core/vpException.h>
#include <visp3/vision/vpHandEyeCalibration.h>

#include <unistd.h>

#include <cmath>
#include <cstdio>

#include "marionette/perception/camera_intrinsics.h"
#include "visp_conversions.h"

namespace marionette::perception {

using internal::FromVisp;
using internal::ToVisp;

namespace {

// Points file descriptor 1 at stderr for its lifetime (process-wide: keep the scope short).
class StdoutToStderr {
 public:
  StdoutToStderr() {
    std::fflush(stdout);
    saved_ = ::dup(STDOUT_FILENO);
    if (saved_ >= 0) ::dup2(STDERR_FILENO, STDOUT_FILENO);
  }
  ~StdoutToStderr() {
    std::fflush(stdout);
    if (saved_ >= 0) {
      ::dup2(saved_, STDOUT_FILENO);
      ::close(saved_);
    }
  }
  StdoutToStderr(const StdoutToStderr&) = delete;
  StdoutToStderr& operator=(const StdoutToStderr&) = delete;

 private:
  int saved_ = -1;
};

}  // namespace

HandEyeResult CalibrateHandEye(const std::vector<Eigen::Isometry3d>& X_RE,
                               const std::vector<Eigen::Isometry3d>& X_CT) {
  if (X_RE.size() != X_CT.size()) {
    throw PerceptionError("CalibrateHandEye: " + std::to_string(X_RE.size()) + " robot poses but " +
                          std::to_string(X_CT.size()) + " target observations");
  }
  if (X_RE.size() < 3) {
    throw PerceptionError("CalibrateHandEye: needs at least 3 pose pairs, got " +
                          std::to_string(X_RE.size()));
  }
  std::vector<vpHomogeneousMatrix> rMe, cMo;
  for (size_t i = 0; i < X_RE.size(); ++i) {
    if (!X_RE[i].matrix().allFinite() || !X_CT[i].matrix().allFinite()) {
      throw PerceptionError("CalibrateHandEye: pose pair " + std::to_string(i) + " is not finite");
    }
    rMe.push_back(ToVisp(X_RE[i]));
    cMo.push_back(ToVisp(X_CT[i]));
  }
  // vpHandEyeCalibration::calibrate runs Tsai-Lenz (and Procrustes) closed forms, keeps the one
  // with the smallest residual and refines it by non-linear least squares. It prints its
  // residuals on stdout: send them to stderr so that stdout stays the caller's.
  vpHomogeneousMatrix eMc;
  int status = -1;
  {
    StdoutToStderr redirect;
    try {
      status = vpHandEyeCalibration::calibrate(cMo, rMe, eMc);
    } catch (const vpException& e) {
      throw PerceptionError(std::string("CalibrateHandEye: ViSP failed: ") + e.what());
    }
  }
  if (status != 0 || !internal::AllFinite(eMc)) {
    throw PerceptionError(
        "CalibrateHandEye: no solution (the effector rotations must span at least two "
        "non-parallel axes)");
  }
  HandEyeResult out;
  out.X_EC = FromVisp(eMc);
  // X_RT from each pair; the mean is taken on the translation and, for the rotation, by
  // averaging quaternions of one hemisphere (fine for the small spread of a good calibration).
  Eigen::Vector3d p_sum = Eigen::Vector3d::Zero();
  Eigen::Vector4d q_sum = Eigen::Vector4d::Zero();
  std::vector<Eigen::Isometry3d> X_RT(X_RE.size());
  for (size_t i = 0; i < X_RE.size(); ++i) {
    X_RT[i] = X_RE[i] * out.X_EC * X_CT[i];
    p_sum += X_RT[i].translation();
    Eigen::Quaterniond q(X_RT[i].linear());
    if (i > 0 && q.coeffs().dot(q_sum) < 0.0) q.coeffs() *= -1.0;
    q_sum += q.coeffs();
  }
  out.X_RT.translation() = p_sum / X_RE.size();
  out.X_RT.linear() = Eigen::Quaterniond(q_sum.normalized()).toRotationMatrix();
  double sp = 0.0, sr = 0.0;
  for (const auto& X : X_RT) {
    sp += (X.translation() - out.X_RT.translation()).squaredNorm();
    const double a = Eigen::AngleAxisd(out.X_RT.linear().transpose() * X.linear()).angle();
    sr += a * a;
  }
  out.rms_position = std::sqrt(sp / X_RT.size());
  out.rms_rotation = std::sqrt(sr / X_RT.size());
  return out;
}

}  // namespace marionette::perception
