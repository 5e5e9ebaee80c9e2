#pragma once
/// Swing-foot trajectory of one step (Dang 2012 §2.6.2: "a polynomial function can be used to
/// calculate desired foot trajectories"): the sole goes from its lift-off placement to its
/// landing placement in `duration` seconds, flat (roll = pitch = 0) all along.
///
/// With s = t / duration ∈ [0, 1] and the quintic blend σ(s) = 10s³ − 15s⁴ + 6s⁵
/// (σ(0) = 0, σ(1) = 1, σ' = σ'' = 0 at both ends), the sole moves along the straight line from
/// lift-off to landing with progress H(s) and rises above it by h V(s):
///   x, y, yaw(s) = from + (to − from) H(s)            (yaw by the shortest way round)
///   z(s)         = z_from + (z_to − z_from) H(s) + h V(s)
/// * A step without via points: H = σ(s), V = b(s) = 64 (s − s²)³. b is 0 at both ends with zero
///   first and second derivatives and peaks at b(½) = 1, so the foot lifts and lands with zero
///   velocity and acceleration (flat landing), h above the straight line at mid-swing.
/// * A step with via points (over an obstacle) rises, crosses and lands: V = σ(s / r) over the
///   first fraction r of the swing, 1 in the middle, σ((1 − s) / r) over the last r; H moves
///   only in the middle, H = σ((s − r) / (1 − 2r)). Every point of the crossing is then h above
///   the line, so h is the highest via point above it and no higher. (A bump with h raised until
///   it clears a via point near an end of the step went 2.5 times higher: a humanoid's trailing
///   leg, landing 3 cm past a bar, was sent 0.55 m up and saturated the stance leg's torques.)
/// Both are C² and start and end at rest.

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
  /// Fraction r of a swing with via points spent rising (and as much landing): a quarter each,
  /// the traverse the middle half (a 1.2 s crossing: 0.15 m up in 0.3 s, 0.5 m across in 0.6 s).
  static constexpr double kRiseFraction = 0.25;
  /// `duration` > 0 [s], `height` >= 0 [m]; `via` (num_via <= kMaxVia points, world [m]) raise
  /// the height so the sole origin passes at or above each point's height wherever it is along
  /// the step (the crossing is level). Throws std::invalid_argument on bad values.
  SwingFoot(const FootPlacement& from, const FootPlacement& to, double duration, double height,
            const Eigen::Vector3d* via = nullptr, int num_via = 0);
  /// The trajectory at time t ∈ [0, duration] after lift-off (clamped outside). No allocation.
  FootSample Sample(double t) const;
  double height() const { return height_; }  ///< h actually used (>= the requested height)
  double duration() const { return duration_; }

 private:
  // H(s) (`along`) and V(s) (`up`) with their first two derivatives with respect to s.
  void Profiles(double s, Blend* along, Blend* up) const;

  FootPlacement from_, delta_;  // delta: to − from with the yaw difference wrapped
  double duration_;
  double height_;
  bool rise_cross_land_ = false;  // via points: the level crossing's profiles
};

}  // namespace marionette::walk
