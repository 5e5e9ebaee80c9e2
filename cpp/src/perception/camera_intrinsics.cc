#include "marionette/perception/camera_intrinsics.h"

#include <cmath>

namespace marionette::perception {

void CameraIntrinsics::Validate() const {
  if (width <= 0 || height <= 0) {
    throw PerceptionError("camera intrinsics: image size must be positive, got " +
                          std::to_string(width) + " x " + std::to_string(height));
  }
  if (!(std::isfinite(fx) && std::isfinite(fy) && fx > 0.0 && fy > 0.0)) {
    throw PerceptionError("camera intrinsics: focal lengths must be finite and > 0, got fx = " +
                          std::to_string(fx) + ", fy = " + std::to_string(fy));
  }
  if (!(std::isfinite(cx) && std::isfinite(cy))) {
    throw PerceptionError("camera intrinsics: principal point must be finite, got cx = " +
                          std::to_string(cx) + ", cy = " + std::to_string(cy));
  }
}

}  // namespace marionette::perception
