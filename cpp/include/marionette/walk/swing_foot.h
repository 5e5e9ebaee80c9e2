#pragma once
/// Swing-foot trajectory of one step (Dang 2012 §2.6.2: "a polynomial function can be used to
/// calculate desired foot trajectories"): the sole goes from its lift-off placement to its
/// landing placement in `duration` seconds, flat (roll = pitch = 0) all along.
///
/// With s = t / duration ∈ [0, 1] and the quintic blend σ(s) = 10s³ − 15s⁴ + 6s⁵
/// (σ(0) = 0, σ(1) = 1, σ' = σ'' = 0 at both ends):
///   x, y, yaw(s) = from + (to − from) σ(s)            (yaw by the shortest way round)
///   z(s)         = z_from + (z_to − z_from) σ(s) + h b(s),   b(s) = 64 (s − s²)³
/// b is 0 at both ends with zero first and second derivatives and peaks at b(½) = 1, so the foot
/// lifts and lands with zero velocity and acceleration (flat landing), h above the straight line
/// at mid-swing. Via points (e.g. over a bar) raise h until the foot passes above each of them.

#include <Eigen/Core>
#include <array>
#include <pinocchio/spatial/se3.hpp>

namespace marionette::walk {

/// A planar sole placement: (x, y, z, yaw) of the sole frame in world [m, rad].
using FootPlacement = Eigen::Vector4d;

/// The sole's pose X_WF (roll = pitch = 0) of a placement.
pinocchio::SE3 PlacementToPose(const FootPlacement& placement);
/// The placement of a pose (yaw of its x axis; roll and pitch dropped).
FootPlacement PoseToPlacement(const pinocchio::SE3& X_WF);
/// `angle` wrapped into (−π, π].
double WrapAngle(double angle);

/// Quintic blend σ(s) and its first two derivatives with respect to s (s clamped to [0, 1]).
struct Blend {
  double value = 0.0, rate = 0.0, acceleration = 0.0;
};
Blend QuinticBlend(double s);
/// Height profile b(s) = 64 (s − s²)³ and its first two derivatives with respect to s.
Blend LiftProfile(double s);

/// Sample of a foot trajectory: pose, and velocity/acceleration (linear of the sole origin,
/// angular; world axes).
struct FootSample {
  pinocchio::SE3 pose;
  Eigen::Matrix<double, 6, 1> velocity = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> acceleration = Eigen::Matrix<double, 6, 1>::Zero();
};

class SwingFoot {
 public:
  static constexpr int kMaxVia = 4;
  /// `duration` > 0 [s], `height` >= 0 [m]; `via` (num_via <= kMaxVia points, world [m]) raise
  /// the height so the sole origin passes at or above each point's height where it crosses the
  /// point's horizontal position along the step. Throws std::invalid_argument on bad values.
  SwingFoot(const FootPlacement& from, const FootPlacement& to, double duration, double height,
            const Eigen::Vector3d* via = nullptr, int num_via = 0);
  /// The trajectory at time t ∈ [0, duration] after lift-off (clamped outside). No allocation.
  FootSample Sample(double t) const;
  double height() const { return height_; }  ///< h actually used (>= the requested height)
  double duration() const { return duration_; }

 private:
  FootPlacement from_, delta_;  // delta: to − from with the yaw difference wrapped
  double duration_;
  double height_;
};

}  // namespace marionette::walk
