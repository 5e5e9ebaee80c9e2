#pragma once
/// Measured ZMP and the support polygon (Dang 2012 §2.4.2): the ZMP of the contact forces
/// (eq. 2.40–2.46) must lie in the convex hull of the soles on the ground.

#include <Eigen/Core>
#include <array>

#include "marionette/walk/swing_foot.h"

namespace marionette::walk {

/// A sole's contact wrench: force and torque (world axes, torque about `origin`, the sole
/// frame's origin on the ground).
struct SoleWrench {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   ///< [N]
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();  ///< [N m]
};

/// ZMP on the ground plane z = ground_z of the wrenches whose normal force exceeds `min_force`
/// [N]: with o_i the sole origins, p_x = Σ(o_ix f_iz − τ_iy − (o_iz − z) f_ix) / Σ f_iz,
/// p_y = Σ(o_iy f_iz + τ_ix − (o_iz − z) f_iy) / Σ f_iz (the moment about p, τ_i + (o_i − p) × f_i
/// summed, has no horizontal part). Returns false (zmp untouched) when no sole carries load.
bool MeasuredZmp(const SoleWrench* wrenches, int count, double ground_z, Eigen::Vector2d* zmp,
                 double min_force = 10.0);

/// A rectangular sole centred on its frame: half length along the sole x axis, half width
/// along y [m] (robot.yaml feet[].size / 2).
struct SoleShape {
  double half_length = 0.1025;
  double half_width = 0.061;
};

/// Convex polygon of up to 8 vertices, counter-clockwise.
struct SupportPolygon {
  std::array<Eigen::Vector2d, 8> vertices{};
  int size = 0;
};

/// The convex hull of the soles at `placements` (1 or 2 of them). No allocation.
SupportPolygon MakeSupportPolygon(const FootPlacement* placements, int count,
                                  const SoleShape& sole = {});

/// Signed distance from `p` to the polygon's boundary: > 0 inside (the margin), < 0 outside.
double SignedMargin(const SupportPolygon& polygon, const Eigen::Vector2d& p);

}  // namespace marionette::walk
