#include "marionette/planning/path_validator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

#include <coal/shape/convex.h>
#include <coal/shape/geometric_shapes.h>
#include <pinocchio/algorithm/geometry.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/collision/collision.hpp>
#include <pinocchio/collision/distance.hpp>
#include <pinocchio/multibody/joint/joints.hpp>

namespace marionette::planning {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// A pair whose bounding spheres are this far apart [m] is certified from that bound alone (a
// lower bound of its distance); closer ones get the exact distance (GJK on the hulls).
constexpr double kSphereMargin = 0.02;

pinocchio::JointIndex AddJoint(pinocchio::Model* model, const JointSpec& j) {
  const auto parent = static_cast<pinocchio::JointIndex>(j.parent);
  const std::string& k = j.kind;
  if (k == "RX") return model->addJoint(parent, pinocchio::JointModelRX(), j.placement, j.name);
  if (k == "RY") return model->addJoint(parent, pinocchio::JointModelRY(), j.placement, j.name);
  if (k == "RZ") return model->addJoint(parent, pinocchio::JointModelRZ(), j.placement, j.name);
  if (k == "RUBX") return model->addJoint(parent, pinocchio::JointModelRUBX(), j.placement, j.name);
  if (k == "RUBY") return model->addJoint(parent, pinocchio::JointModelRUBY(), j.placement, j.name);
  if (k == "RUBZ") return model->addJoint(parent, pinocchio::JointModelRUBZ(), j.placement, j.name);
  if (k == "PX") return model->addJoint(parent, pinocchio::JointModelPX(), j.placement, j.name);
  if (k == "PY") return model->addJoint(parent, pinocchio::JointModelPY(), j.placement, j.name);
  if (k == "PZ") return model->addJoint(parent, pinocchio::JointModelPZ(), j.placement, j.name);
  if (k == "RevoluteUnaligned")
    return model->addJoint(parent, pinocchio::JointModelRevoluteUnaligned(j.axis), j.placement,
                           j.name);
  if (k == "PrismaticUnaligned")
    return model->addJoint(parent, pinocchio::JointModelPrismaticUnaligned(j.axis), j.placement,
                           j.name);
  if (k == "FreeFlyer")
    return model->addJoint(parent, pinocchio::JointModelFreeFlyer(), j.placement, j.name);
  throw std::invalid_argument("joint " + j.name + ": kind '" + k +
                              "' is not supported (RX RY RZ RUBX RUBY RUBZ PX PY PZ "
                              "RevoluteUnaligned PrismaticUnaligned FreeFlyer)");
}

std::shared_ptr<coal::CollisionGeometry> MakeShape(const GeometrySpec& g) {
  if (g.kind == "convex") {
    if (g.points.rows() < 4 || g.triangles.rows() < 4)
      throw std::invalid_argument("geometry " + g.name +
                                  ": a convex hull needs >= 4 points and "
                                  ">= 4 triangles");
    auto pts = std::make_shared<std::vector<coal::Vec3s>>();
    for (Eigen::Index i = 0; i < g.points.rows(); ++i)
      pts->emplace_back(g.points.row(i).transpose());
    auto tris = std::make_shared<std::vector<coal::Triangle>>();
    for (Eigen::Index i = 0; i < g.triangles.rows(); ++i) {
      for (int c = 0; c < 3; ++c)
        if (g.triangles(i, c) < 0 || g.triangles(i, c) >= g.points.rows())
          throw std::invalid_argument("geometry " + g.name +
                                      ": triangle vertex index out of range");
      tris->emplace_back(g.triangles(i, 0), g.triangles(i, 1), g.triangles(i, 2));
    }
    return std::make_shared<coal::Convex<coal::Triangle>>(
        pts, static_cast<unsigned>(pts->size()), tris, static_cast<unsigned>(tris->size()));
  }
  if (g.kind == "box") return std::make_shared<coal::Box>(2.0 * g.half_side);
  if (g.kind == "sphere") return std::make_shared<coal::Sphere>(g.radius);
  if (g.kind == "cylinder") return std::make_shared<coal::Cylinder>(g.radius, 2.0 * g.half_length);
  if (g.kind == "capsule") return std::make_shared<coal::Capsule>(g.radius, 2.0 * g.half_length);
  throw std::invalid_argument("geometry " + g.name + ": kind '" + g.kind +
                              "' is not supported (convex box sphere cylinder capsule)");
}

}  // namespace

pinocchio::Model BuildKinematicModel(const std::vector<JointSpec>& joints) {
  pinocchio::Model model;
  for (const JointSpec& j : joints) {
    if (j.parent < 0 || j.parent >= model.njoints)
      throw std::invalid_argument("joint " + j.name + ": parent " + std::to_string(j.parent) +
                                  " is not defined before it");
    const pinocchio::JointIndex id = AddJoint(&model, j);
    if (j.mass > 0.0)
      model.appendBodyToJoint(
          id, pinocchio::Inertia(j.mass, j.lever, pinocchio::Symmetric3(j.rotational_inertia)));
  }
  return model;
}

pinocchio::GeometryModel BuildGeometryModel(const pinocchio::Model& model,
                                            const std::vector<GeometrySpec>& geometries,
                                            const std::vector<std::pair<int, int>>& pairs) {
  pinocchio::GeometryModel gm;
  for (const GeometrySpec& g : geometries) {
    if (g.parent_joint < 0 || g.parent_joint >= model.njoints)
      throw std::invalid_argument("geometry " + g.name + ": parent joint " +
                                  std::to_string(g.parent_joint) + " out of range");
    gm.addGeometryObject(pinocchio::GeometryObject(
        g.name, static_cast<pinocchio::JointIndex>(g.parent_joint), g.placement, MakeShape(g)));
  }
  const int n = static_cast<int>(geometries.size());
  for (const auto& [a, b] : pairs) {
    if (a < 0 || b < 0 || a >= n || b >= n || a == b)
      throw std::invalid_argument("collision pair (" + std::to_string(a) + ", " +
                                  std::to_string(b) + ") invalid for " + std::to_string(n) +
                                  " geometries");
    gm.addCollisionPair(pinocchio::CollisionPair(a, b));
  }
  return gm;
}

PathValidator::PathValidator(pinocchio::Model model, pinocchio::GeometryModel geom_model,
                             double contact, int max_queries)
    : model_(std::move(model)),
      data_(model_),
      geom_model_(std::move(geom_model)),
      geom_data_(geom_model_),
      contact_(contact),
      max_queries_(max_queries) {
  if (!(contact_ > 0.0)) throw std::invalid_argument("contact distance must be > 0");
  if (max_queries_ < 1) throw std::invalid_argument("max_queries must be >= 1");
  kinds_.assign(model_.njoints, Kind::kRevolute);
  for (int j = 1; j < model_.njoints; ++j) {
    const int nv = model_.joints[j].nv();
    const std::string name = model_.joints[j].shortname();
    if (nv == 6) {
      kinds_[j] = Kind::kFreeFlyer;
    } else if (nv == 1) {
      kinds_[j] = name.find("Prismatic") != std::string::npos || name == "JointModelPX" ||
                          name == "JointModelPY" || name == "JointModelPZ"
                      ? Kind::kPrismatic
                      : Kind::kRevolute;
    } else {
      throw std::invalid_argument("joint " + model_.names[j] + " (" + name + ") is not supported");
    }
  }
  for (auto& g : geom_model_.geometryObjects) {
    g.geometry->computeLocalAABB();
    sphere_center_.push_back(g.geometry->aabb_center);
    sphere_radius_.push_back(g.geometry->aabb_radius);
  }
  q_.resize(model_.nq);
  qa_.resize(model_.nq);
  ea_.resize(model_.nq);
  eb_.resize(model_.nq);
  qb_.resize(model_.nq);
  dv_.resize(model_.nv);
  ang_.resize(model_.njoints);
  lin_.resize(model_.njoints);
  const int np = num_pairs();
  u_.resize(np);
  threshold_.resize(np);
  horizon_.resize(np);
  budget_.resize(np);
}

void PathValidator::CheckSizes(const Polyline& path, const Substitution& sub,
                               const PairMotion& motion) const {
  if (path.points.rows() < 2 || path.points.cols() != model_.nq)
    throw std::invalid_argument("path points must be (k >= 2) x nq = " + std::to_string(model_.nq) +
                                ", got " + std::to_string(path.points.rows()) + " x " +
                                std::to_string(path.points.cols()));
  if (path.cum.size() != path.points.rows())
    throw std::invalid_argument("cum must have one arc length per point");
  const int np = num_pairs();
  if (motion.rigid.size() != np || motion.skip.size() != np || motion.R.rows() != np ||
      motion.L.rows() != np || motion.R.cols() != model_.njoints ||
      motion.L.cols() != model_.njoints ||
      (motion.clearance.size() != 0 && motion.clearance.size() != np))
    throw std::invalid_argument(
        "pair motion must be sized npairs = " + std::to_string(np) +
        " (rigid, skip, clearance if given) and npairs x njoints = " + std::to_string(np) + " x " +
        std::to_string(model_.njoints) + " (R, L)");
  if (sub.locked_idx_q.size() != sub.locked_value.size() ||
      sub.attached_idx_q.size() != sub.attached_parent.size() ||
      sub.attached_idx_q.size() != sub.attached_M_PO.size())
    throw std::invalid_argument("substitution lists must have matching lengths");
  for (size_t i = 0; i < sub.locked_idx_q.size(); ++i)
    if (sub.locked_idx_q[i] < 0 || sub.locked_idx_q[i] + sub.locked_value[i].size() > model_.nq)
      throw std::invalid_argument("locked joint value out of the configuration");
  for (size_t i = 0; i < sub.attached_idx_q.size(); ++i)
    if (sub.attached_idx_q[i] < 0 || sub.attached_idx_q[i] + 7 > model_.nq ||
        sub.attached_parent[i] < 0 || sub.attached_parent[i] >= model_.njoints)
      throw std::invalid_argument("attached free-flyer out of the model");
}

void PathValidator::Eval(const Polyline& path, const Substitution& sub, double s,
                         Eigen::VectorXd* q) {
  const Eigen::Index k = path.points.rows();
  const double length = path.cum[k - 1];
  if (s <= 0.0 || s >= length) {
    *q = path.points.row(s <= 0.0 ? 0 : k - 1).transpose();
    return;
  }
  // Pinocchio's Lie-group operations need contiguous vectors: the rows of the column-major
  // points matrix are strided (a free-flyer's quaternion came out wrong), hence the copies.
  if (k == 2) {
    ea_ = path.points.row(0).transpose();
    eb_ = path.points.row(1).transpose();
    pinocchio::interpolate(model_, ea_, eb_, std::min(std::max(s / length, 0.0), 1.0), *q);
  } else {
    // numpy.searchsorted(cum, s, side="right") - 1: the last vertex at or before s.
    const double* c = path.cum.data();
    Eigen::Index i = std::upper_bound(c, c + k, s) - c - 1;
    i = std::min(i, k - 2);
    const double ds = c[i + 1] - c[i];
    const double u = ds <= 0.0 ? 0.0 : (s - c[i]) / ds;
    ea_ = path.points.row(i).transpose();
    eb_ = path.points.row(i + 1).transpose();
    pinocchio::interpolate(model_, ea_, eb_, u, *q);
  }
  Substitute(sub, q);
}

void PathValidator::Substitute(const Substitution& sub, Eigen::VectorXd* q) {
  // Substitution (projector.apply_explicit): locked values, then attached objects from one
  // forward kinematics (their parents are never outputs of another substitution).
  for (size_t j = 0; j < sub.locked_idx_q.size(); ++j)
    q->segment(sub.locked_idx_q[j], sub.locked_value[j].size()) = sub.locked_value[j];
  if (!sub.attached_idx_q.empty()) {
    pinocchio::forwardKinematics(model_, data_, *q);
    for (size_t j = 0; j < sub.attached_idx_q.size(); ++j) {
      const pinocchio::SE3 X_WO = data_.oMi[sub.attached_parent[j]] * sub.attached_M_PO[j];
      const Eigen::Quaterniond quat(X_WO.rotation());
      q->segment<3>(sub.attached_idx_q[j]) = X_WO.translation();
      q->segment<4>(sub.attached_idx_q[j] + 3) = quat.coeffs();  // x y z w
    }
  }
}

void PathValidator::Update(const Eigen::VectorXd& q) {
  pinocchio::updateGeometryPlacements(model_, data_, geom_model_, geom_data_, q);
}

double PathValidator::SphereBound(int p) const {
  const pinocchio::CollisionPair& cp = geom_model_.collisionPairs[p];
  const pinocchio::SE3& Xa = geom_data_.oMg[cp.first];
  const pinocchio::SE3& Xb = geom_data_.oMg[cp.second];
  return (Xa.act(sphere_center_[cp.first]) - Xb.act(sphere_center_[cp.second])).norm() -
         sphere_radius_[cp.first] - sphere_radius_[cp.second];
}

bool PathValidator::IsValid(const Eigen::VectorXd& q,
                            const Eigen::Array<bool, Eigen::Dynamic, 1>& skip) {
  if (q.size() != model_.nq) throw std::invalid_argument("q must have nq entries");
  if (skip.size() != num_pairs()) throw std::invalid_argument("skip must have npairs entries");
  Update(q);
  for (int k = 0; k < num_pairs(); ++k)
    if (!skip[k] && SphereBound(k) <= contact_ &&
        pinocchio::computeCollision(geom_model_, geom_data_, k))
      return false;
  return true;
}

double PathValidator::DistanceWithin(int p, double within) {
  const double bound = SphereBound(p);
  return bound <= within ? pinocchio::computeDistance(geom_model_, geom_data_, p).min_distance
                         : bound;
}

bool PathValidator::IsClear(const Eigen::VectorXd& q, const PairMotion& motion) {
  if (q.size() != model_.nq) throw std::invalid_argument("q must have nq entries");
  if (motion.skip.size() != num_pairs() ||
      (motion.clearance.size() != 0 && motion.clearance.size() != num_pairs()))
    throw std::invalid_argument("skip and clearance must have npairs entries");
  Update(q);
  for (int k = 0; k < num_pairs(); ++k) {
    if (motion.skip[k]) continue;
    const double keep =
        motion.clearance.size() == 0 ? contact_ : std::max(contact_, motion.clearance[k]);
    if (DistanceWithin(k, keep) <= keep) return false;
  }
  return true;
}

void PathValidator::SetThresholds(const Polyline& path, const PairMotion& motion) {
  threshold_.setConstant(contact_);
  if (motion.clearance.size() == 0) return;
  std::vector<int> kept;  // pairs that keep a clearance beyond contact, unless an end excuses them
  for (int p = 0; p < num_pairs(); ++p) {
    if (motion.rigid[p] || motion.skip[p] || !(motion.clearance[p] > contact_)) continue;
    threshold_[p] = motion.clearance[p];
    kept.push_back(p);
  }
  if (kept.empty()) return;
  for (const Eigen::Index end : {Eigen::Index{0}, path.points.rows() - 1}) {
    Update(path.points.row(end).transpose());
    for (const int p : kept)
      if (DistanceWithin(p, threshold_[p]) <= threshold_[p]) threshold_[p] = contact_;
  }
}

Eigen::VectorXd PathValidator::Distances(const Eigen::VectorXd& q) {
  if (q.size() != model_.nq) throw std::invalid_argument("q must have nq entries");
  Update(q);
  Eigen::VectorXd d(num_pairs());
  for (int k = 0; k < num_pairs(); ++k)
    d[k] = pinocchio::computeDistance(geom_model_, geom_data_, k).min_distance;
  return d;
}

ValidationResult PathValidator::Validate(const Polyline& path, const Substitution& sub,
                                         const PairMotion& motion, bool probes) {
  CheckSizes(path, sub, motion);
  ValidationResult out;
  const Eigen::Index k = path.points.rows();
  const double length = path.cum[k - 1];
  if (probes) {
    // All or nothing: cheap discrete probes (dichotomy order) reject most colliding paths
    // before any certified stepping.
    for (double frac : {0.5, 0.25, 0.75}) {
      Eval(path, sub, frac * length, &q_);
      if (!IsValid(q_, motion.skip)) return out;
    }
  }
  SetThresholds(path, motion);
  Update(path.points.row(0).transpose());
  // Pairs that do not move relatively: checked once, at the start.
  for (int p = 0; p < num_pairs(); ++p) {
    if (motion.rigid[p] && !motion.skip[p]) {
      ++out.queries;
      if (SphereBound(p) <= contact_ && pinocchio::computeCollision(geom_model_, geom_data_, p))
        return out;
    }
  }
  // Certified displacement left to each pair, carried from segment to segment.
  budget_.setZero();
  for (Eigen::Index i = 0; i + 1 < k; ++i) {
    double t = 1.0;
    if (!ValidateSegment(path, sub, static_cast<int>(i), motion, &out, &t)) {
      out.s_valid = path.cum[i] + t * (path.cum[i + 1] - path.cum[i]);
      return out;
    }
  }
  out.valid = true;
  out.s_valid = length;
  return out;
}

void PathValidator::PairSpeeds(const Eigen::VectorXd& qa, const Eigen::VectorXd& qb,
                               const PairMotion& motion, Eigen::VectorXd* u) {
  // Displacement of each joint over the segment (per unit t): |angle| for revolute joints,
  // |translation| for prismatic ones, both norms for free-flyers.
  pinocchio::difference(model_, qa, qb, dv_);
  ang_.setZero();
  lin_.setZero();
  for (int j = 1; j < model_.njoints; ++j) {
    const int iv = model_.idx_vs[j];
    switch (kinds_[j]) {
      case Kind::kRevolute:
        ang_[j] = std::abs(dv_[iv]);
        break;
      case Kind::kPrismatic:
        lin_[j] = std::abs(dv_[iv]);
        break;
      case Kind::kFreeFlyer:
        lin_[j] = dv_.segment<3>(iv).norm();
        ang_[j] = dv_.segment<3>(iv + 3).norm();
        break;
    }
  }
  // A point of a body moves at most u |dt| (collision.py's docstring): a pair at distance d
  // at t stays apart on |t' - t| < d / u.
  u->noalias() = motion.R * ang_;
  u->noalias() += motion.L * lin_;
  for (int p = 0; p < num_pairs(); ++p)
    if (motion.rigid[p] || motion.skip[p]) (*u)[p] = 0.0;
}

bool PathValidator::ValidateSegment(const Polyline& path, const Substitution& sub, int i,
                                    const PairMotion& motion, ValidationResult* out,
                                    double* t_fail) {
  qa_ = path.points.row(i).transpose();
  qb_ = path.points.row(i + 1).transpose();
  PairSpeeds(qa_, qb_, motion, &u_);
  const int np = num_pairs();
  bool any = false;
  for (int p = 0; p < np; ++p) {
    const bool moving = u_[p] > 0.0;
    horizon_[p] = moving ? budget_[p] / u_[p] : kInf;
    any = any || moving;
  }
  if (!any) return true;
  const double s0 = path.cum[i];
  const double length = path.cum[i + 1] - s0;
  double t = 0.0;
  for (int it = 0; it < max_queries_; ++it) {
    // Pairs due within the next 1 % of the segment are refreshed now as well: one forward
    // kinematics then serves several pairs (their certified intervals stay contiguous).
    bool updated = false;
    for (int p = 0; p < np; ++p) {
      if (horizon_[p] > t + 0.01) continue;
      if (!updated) {
        Eval(path, sub, s0 + t * length, &q_);
        Update(q_);
        updated = true;
      }
      const double bound = SphereBound(p);
      double d = bound;
      if (bound <= kSphereMargin + threshold_[p]) {
        ++out->queries;
        d = pinocchio::computeDistance(geom_model_, geom_data_, p).min_distance;
      }
      if (d <= threshold_[p]) {
        *t_fail = t;
        return false;
      }
      horizon_[p] = t + (d - threshold_[p]) / u_[p];
    }
    const double t_next = horizon_.minCoeff();
    if (t_next >= 1.0) {
      for (int p = 0; p < np; ++p)
        if (std::isfinite(horizon_[p])) budget_[p] = (horizon_[p] - 1.0) * u_[p];
      return true;
    }
    // d > threshold at every query, but a pair may hug its threshold: the query budget ends it.
    t = t_next;
  }
  // Bodies grazing each other along the whole segment: not certifiable, refused.
  out->grazing = true;
  *t_fail = t;
  return false;
}

}  // namespace marionette::planning
