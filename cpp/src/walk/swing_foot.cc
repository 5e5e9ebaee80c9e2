#include "marionette/walk/swing_foot.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace marionette::walk {

pinocchio::SE3 PlacementToPose(const FootPlacement& p) {
  const double c = std::cos(p[3]), s = std::sin(p[3]);
  Eigen::Matrix3d R;
  R << c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0;
  return pinocchio::SE3(R, p.head<3>());
}

FootPlacement PoseToPlacement(const pinocchio::SE3& X) {
  const Eigen::Vector3d& p = X.translation();
  return FootPlacement(p[0], p[1], p[2], std::atan2(X.rotation()(1, 0), X.rotation()(0, 0)));
}

double WrapAngle(double a) {
  a = std::remainder(a, 2.0 * M_PI);  // in [−π, π]
  return a <= -M_PI ? a + 2.0 * M_PI : a;
}

Blend QuinticBlend(double s) {
  s = std::clamp(s, 0.0, 1.0);
  const double s2 = s * s, s3 = s2 * s;
  return {s3 * (10.0 - 15.0 * s + 6.0 * s2), 30.0 * s2 * (1.0 - s) * (1.0 - s),
          60.0 * s * (1.0 - s) * (1.0 - 2.0 * s)};
}

Blend LiftProfile(double s) {
  s = std::clamp(s, 0.0, 1.0);
  // b = 64 w³ with w = s − s², w' = 1 − 2s, w'' = −2.
  const double w = s - s * s, dw = 1.0 - 2.0 * s;
  return {64.0 * w * w * w, 192.0 * w * w * dw, 192.0 * (2.0 * w * dw * dw - 2.0 * w * w)};
}

SwingFoot::SwingFoot(const FootPlacement& from, const FootPlacement& to, double duration,
                     double height, const Eigen::Vector3d* via, int num_via)
    : from_(from), duration_(duration), height_(height) {
  if (!from.allFinite() || !to.allFinite())
    throw std::invalid_argument("SwingFoot: non-finite placement");
  if (!(duration > 0.0) || !std::isfinite(duration)) {
    throw std::invalid_argument("SwingFoot: duration must be > 0 s, got " +
                                std::to_string(duration));
  }
  if (!(height >= 0.0) || !std::isfinite(height)) {
    throw std::invalid_argument("SwingFoot: height must be >= 0 m, got " + std::to_string(height));
  }
  if (num_via < 0 || num_via > kMaxVia || (num_via > 0 && via == nullptr)) {
    throw std::invalid_argument("SwingFoot: at most " + std::to_string(kMaxVia) + " via points");
  }
  delta_ = to - from;
  delta_[3] = WrapAngle(to[3] - from[3]);
  rise_cross_land_ = num_via > 0;
  const Eigen::Vector2d d = delta_.head<2>();
  const double length2 = d.squaredNorm();
  for (int i = 0; i < num_via; ++i) {
    if (!via[i].allFinite()) throw std::invalid_argument("SwingFoot: non-finite via point");
    // The crossing is level at h above the line: h clears the point where the sole passes its
    // horizontal position (a fraction of the line, clamped to the line's ends).
    const double fraction =
        length2 > 1e-12 ? std::clamp((via[i].head<2>() - from.head<2>()).dot(d) / length2, 0.0, 1.0)
                        : 0.5;
    height_ = std::max(height_, via[i][2] - (from[2] + delta_[2] * fraction));
  }
}

void SwingFoot::Profiles(double s, Blend* along, Blend* up) const {
  if (!rise_cross_land_) {
    *along = QuinticBlend(s);
    *up = LiftProfile(s);
    return;
  }
  constexpr double r = kRiseFraction, middle = 1.0 - 2.0 * r;
  const Blend across = QuinticBlend((s - r) / middle);
  *along = {across.value, across.rate / middle, across.acceleration / (middle * middle)};
  if (s < r) {
    const Blend v = QuinticBlend(s / r);
    *up = {v.value, v.rate / r, v.acceleration / (r * r)};
  } else if (s > 1.0 - r) {
    const Blend v = QuinticBlend((1.0 - s) / r);
    *up = {v.value, -v.rate / r, v.acceleration / (r * r)};
  } else {
    *up = {1.0, 0.0, 0.0};
  }
}

FootSample SwingFoot::Sample(double t) const {
  const double s = std::clamp(t / duration_, 0.0, 1.0);
  Blend q, b;
  Profiles(s, &q, &b);
  const double k1 = 1.0 / duration_, k2 = k1 * k1;  // d/dt = (1/D) d/ds
  FootSample out;
  FootPlacement p = from_ + delta_ * q.value;
  p[2] += height_ * b.value;
  out.pose = PlacementToPose(p);
  for (int i = 0; i < 2; ++i) {
    out.velocity[i] = delta_[i] * q.rate * k1;
    out.acceleration[i] = delta_[i] * q.acceleration * k2;
  }
  out.velocity[2] = (delta_[2] * q.rate + height_ * b.rate) * k1;
  out.acceleration[2] = (delta_[2] * q.acceleration + height_ * b.acceleration) * k2;
  out.velocity[5] = delta_[3] * q.rate * k1;  // yaw rate about world z
  out.acceleration[5] = delta_[3] * q.acceleration * k2;
  return out;
}

}  // namespace marionette::walk
