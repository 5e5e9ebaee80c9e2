// Certified continuous collision checking of constrained polylines (thesis 000 §3.2.3;
// HPP hpp-core continuous-validation "Progressive"/"Dichotomy" with body-pair velocity bounds).
// C++ twin of marionette.planning.collision.CollisionChecker.validate: same model, same
// geometry (convex hulls built in Python), same bounds, same tolerance; only faster.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/geometry.hpp>
#include <pinocchio/multibody/model.hpp>
#include <pinocchio/spatial/se3.hpp>

namespace marionette::planning {

/// One joint of the kinematic tree, in Pinocchio's order (joint 0, the universe, excluded).
/// kind: Pinocchio short name without "JointModel": RX RY RZ RevoluteUnaligned RUBX RUBY RUBZ
/// PX PY PZ PrismaticUnaligned FreeFlyer.  axis: for the *Unaligned kinds.
struct JointSpec {
  std::string name;
  int parent = 0;
  std::string kind;
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
  pinocchio::SE3 placement = pinocchio::SE3::Identity();  // X_parent_joint (at q = neutral)
  // Body attached to the joint (Pinocchio's model.inertias[joint]): what a centre of mass
  // needs; the path validator ignores it.
  double mass = 0.0;
  Eigen::Vector3d lever = Eigen::Vector3d::Zero();               // CoM in the joint frame
  Eigen::Matrix3d rotational_inertia = Eigen::Matrix3d::Zero();  // about the CoM [kg m^2]
};

/// One collision geometry.  kind: "convex" (points (n x 3), triangles (m x 3) of the hull),
/// "box" (half_side), "sphere" (radius), "cylinder"/"capsule" (radius, half_length).
struct GeometrySpec {
  std::string name;
  int parent_joint = 0;
  pinocchio::SE3 placement = pinocchio::SE3::Identity();  // X_joint_geometry
  std::string kind;
  Eigen::MatrixX3d points;
  Eigen::MatrixX3i triangles;
  Eigen::Vector3d half_side = Eigen::Vector3d::Zero();
  double radius = 0.0;
  double half_length = 0.0;
};

/// Explicit constraints substituted at every evaluation of a path (marionette.planning
/// projector.apply_explicit): locked joints first, then free-flyers attached to a joint
/// (X_WO = oMi[parent] * M_PO, written as xyz + quaternion xyzw at idx_q).
struct Substitution {
  std::vector<int> locked_idx_q;
  std::vector<Eigen::VectorXd> locked_value;
  std::vector<int> attached_idx_q;
  std::vector<int> attached_parent;
  std::vector<pinocchio::SE3> attached_M_PO;
};

/// How fast each collision pair can close its distance: u_k = R(k,:) w + L(k,:) v, with w, v
/// the angular / linear displacement of every joint over a segment (npairs x njoints each).
/// rigid pairs are checked at the start of a path only; skipped pairs never (grasp contacts).
/// clearance (npairs, or empty: the contact distance for every pair) is the distance a moving
/// pair keeps along a path [m]: on a free motion, the robot and what it carries stay that far
/// from what stays in place. A pair already closer than its clearance at one end of a path (a
/// given start, goal or waypoint placed close) keeps only the contact distance on that path.
struct PairMotion {
  Eigen::Array<bool, Eigen::Dynamic, 1> rigid;  // (npairs)
  Eigen::Array<bool, Eigen::Dynamic, 1> skip;   // (npairs)
  Eigen::MatrixXd R;                            // (npairs x njoints) [m / rad]
  Eigen::MatrixXd L;                            // (npairs x njoints) [1]
  Eigen::VectorXd clearance;                    // (npairs) [m], or empty
};

/// Polyline of a constrained path: points (k x nq) at arc lengths cum (k), cum(0) = 0.
/// Evaluation at s interpolates on the configuration manifold then substitutes; the two ends
/// are returned exactly, without substitution (consecutive paths join exactly).
struct Polyline {
  Eigen::MatrixXd points;  // (k x nq)
  Eigen::VectorXd cum;     // (k)
};

struct ValidationResult {
  bool valid = false;
  double s_valid = 0.0;  // the path is collision-free on [0, s_valid] (arc length)
  int64_t queries = 0;   // pair queries made (statistics)
  bool grazing = false;  // refused after max_queries on one segment (bodies grazing)
};

/// Builds a Pinocchio model (kinematics only: no inertias) from joint specs.
/// Throws std::invalid_argument on an unknown kind or a parent not yet defined.
pinocchio::Model BuildKinematicModel(const std::vector<JointSpec>& joints);

/// Builds the geometry model; pairs are (geometry index, geometry index) in the caller's order.
pinocchio::GeometryModel BuildGeometryModel(const pinocchio::Model& model,
                                            const std::vector<GeometrySpec>& geometries,
                                            const std::vector<std::pair<int, int>>& pairs);

/// Certified path validation (see the file comment).  One instance per thread: it owns its
/// Pinocchio and geometry data.
class PathValidator {
 public:
  /// contact [m]: two bodies this close are in collision; max_queries: evaluations of one
  /// segment before it is refused as grazing.
  PathValidator(pinocchio::Model model, pinocchio::GeometryModel geom_model, double contact,
                int max_queries);
  // GeometryData's collision functors point into geom_model_: the object never moves.
  PathValidator(const PathValidator&) = delete;
  PathValidator& operator=(const PathValidator&) = delete;

  /// Progressive certified validation (probes = false) or all-or-nothing (probes = true: the
  /// configurations at 1/2, 1/4, 3/4 of the length are checked first, s_valid = 0 on failure).
  ValidationResult Validate(const Polyline& path, const Substitution& sub, const PairMotion& motion,
                            bool probes);

  /// Configuration at arc length s (nq), exactly as marionette.planning.path.ConstrainedPath.eval.
  void Eval(const Polyline& path, const Substitution& sub, double s, Eigen::VectorXd* q);

  /// Writes the explicit constraints of sub into q (nq): locked values, then attached objects
  /// from one forward kinematics (projector.apply_explicit).
  void Substitute(const Substitution& sub, Eigen::VectorXd* q);

  /// Bound on how fast each pair closes its distance along qa -> qb, per unit of the segment
  /// parameter (npairs) [m]; 0 for rigid and skipped pairs.
  void PairSpeeds(const Eigen::VectorXd& qa, const Eigen::VectorXd& qb, const PairMotion& motion,
                  Eigen::VectorXd* u);

  /// True when no pair except the skipped ones is in collision at q (nq).
  bool IsValid(const Eigen::VectorXd& q, const Eigen::Array<bool, Eigen::Dynamic, 1>& skip);

  /// True when every pair but the skipped ones is farther than its clearance at q (nq): what a
  /// configuration a planner creates on a free motion must keep (then no path from it is
  /// excused from the clearance).
  bool IsClear(const Eigen::VectorXd& q, const PairMotion& motion);

  /// Distance of every pair at q (npairs) [m].
  Eigen::VectorXd Distances(const Eigen::VectorXd& q);

  const pinocchio::Model& model() const { return model_; }
  int num_pairs() const { return static_cast<int>(geom_model_.collisionPairs.size()); }

 private:
  enum class Kind { kRevolute, kPrismatic, kFreeFlyer };
  // Lower bound of pair p's distance from the geometries' bounding spheres (placements as last
  // updated): |c_a - c_b| - r_a - r_b.  Far pairs are certified with it, no GJK query.
  double SphereBound(int p) const;
  // Distance of pair p as last updated, exact (GJK) only when its bounding spheres are closer
  // than `within`.
  double DistanceWithin(int p, double within);
  // threshold_: the distance each pair keeps on this path (its clearance, or the contact
  // distance where an end of the path is already closer; see PairMotion).
  void SetThresholds(const Polyline& path, const PairMotion& motion);
  bool ValidateSegment(const Polyline& path, const Substitution& sub, int i,
                       const PairMotion& motion, ValidationResult* out, double* t_fail);
  void Update(const Eigen::VectorXd& q);
  void CheckSizes(const Polyline& path, const Substitution& sub, const PairMotion& motion) const;

  pinocchio::Model model_;
  pinocchio::Data data_;
  pinocchio::GeometryModel geom_model_;
  pinocchio::GeometryData geom_data_;
  double contact_;
  int max_queries_;
  std::vector<Kind> kinds_;                     // per joint (index 0 unused)
  Eigen::VectorXd threshold_;                   // per pair, for the path being validated
  std::vector<Eigen::Vector3d> sphere_center_;  // per geometry, in its own frame
  std::vector<double> sphere_radius_;
  Eigen::VectorXd q_, qa_, qb_, ea_, eb_, dv_, ang_, lin_, u_, horizon_, budget_;
};

}  // namespace marionette::planning
