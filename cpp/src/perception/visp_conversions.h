#pragma once
// Eigen <-> ViSP conversions, private to the perception library (ViSP never leaks to headers).

#include <visp3/core/vpCameraParameters.h>
#include <visp3/core/vpHomogeneousMatrix.h>

#include <Eigen/Geometry>

#include "marionette/perception/camera_intrinsics.h"

namespace marionette::perception::internal {

inline vpHomogeneousMatrix ToVisp(const Eigen::Isometry3d& X) {
  vpHomogeneousMatrix M;
  for (unsigned r = 0; r < 3; ++r) {
    for (unsigned c = 0; c < 4; ++c) M[r][c] = X.matrix()(r, c);
  }
  return M;
}

/// ViSP's rotations drift from orthonormal at ~1e-12; re-project through a unit quaternion.
inline Eigen::Isometry3d FromVisp(const vpHomogeneousMatrix& M) {
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  for (unsigned r = 0; r < 3; ++r) {
    t[r] = M[r][3];
    for (unsigned c = 0; c < 3; ++c) R(r, c) = M[r][c];
  }
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Quaterniond(R).normalized().toRotationMatrix();
  X.translation() = t;
  return X;
}

inline vpCameraParameters ToVisp(const CameraIntrinsics& k) {
  vpCameraParameters cam;
  cam.initPersProjWithoutDistortion(k.fx, k.fy, k.cx, k.cy);
  return cam;
}

inline bool AllFinite(const vpHomogeneousMatrix& M) {
  for (unsigned r = 0; r < 3; ++r) {
    for (unsigned c = 0; c < 4; ++c) {
      if (!std::isfinite(M[r][c])) return false;
    }
  }
  return true;
}

}  // namespace marionette::perception::internal
