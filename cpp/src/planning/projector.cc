#include "marionette/planning/projector.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/math/quaternion.hpp>
#include <pinocchio/spatial/explog.hpp>

namespace marionette::planning {
namespace {

using Matrix6x = Eigen::Matrix<double, 6, Eigen::Dynamic>;

// Rows of the 6-D relative-pose value [p, log3 R] a placement and its complement read
// (Python constraints.Placement.ROWS / PlacementComplement.ROWS).
constexpr int kPlacementRows[3] = {2, 3, 4};
constexpr int kComplementRows[3] = {0, 1, 5};

void WritePose(const pinocchio::SE3& X, Eigen::Ref<Eigen::VectorXd> q, int idx_q) {
  // xyz + quaternion (x y z w), as pinocchio.SE3ToXYZQUAT.
  Eigen::Quaterniond quat;
  pinocchio::quaternion::assignQuaternion(quat, X.rotation());
  q.segment<3>(idx_q) = X.translation();
  q.segment<4>(idx_q + 3) = quat.coeffs();
}

pinocchio::SE3 ReadPose(const Eigen::Ref<const Eigen::VectorXd>& v, int idx) {
  const Eigen::Quaterniond quat(v[idx + 6], v[idx + 3], v[idx + 4], v[idx + 5]);
  return pinocchio::SE3(quat.toRotationMatrix(),
                        v.segment<3>(idx));  // not normalised, as pinocchio.XYZQUATToSE3
}

// Python's float modulo (result has the divisor's sign): the complement's angle wrap.
double PyMod(double x, double m) {
  double r = std::fmod(x, m);
  if (r != 0.0 && ((m < 0) != (r < 0))) r += m;
  return r;
}

// HPP ErrorNormBased: alpha = C - K tanh(a r + b), r = |e|^2 / eps^2 (projector._error_norm_alpha).
double ErrorNormAlpha(double r, double alpha_min) {
  const double C = 0.5 + alpha_min / 2, K = (1 - alpha_min) / 2;
  const double a = std::atanh((0.02 - 1 + C) / K) / (1 - 1e6);
  const double b = -1e6 * a;
  return C - K * std::tanh(a * r + b);
}

// Offset of the point c from a convex polygon (c - nearest point, zero inside) and its
// derivative with respect to c: n n^T on an edge of outward normal n, I at a vertex
// (constraints._Polygon.offset, HPP ConvexShapeContact).
bool PolygonOffset(const Eigen::MatrixX2d& poly, double x, double y, Eigen::Vector2d* r,
                   Eigen::Matrix2d* D) {
  const Eigen::Index k = poly.rows();
  bool inside = true;
  for (Eigen::Index i = 0; i < k && inside; ++i) {
    const Eigen::Vector2d ab = poly.row((i + 1) % k) - poly.row(i);
    const Eigen::Vector2d n = Eigen::Vector2d(ab.y(), -ab.x()) / ab.norm();
    const Eigen::Vector2d ca = Eigen::Vector2d(x, y) - poly.row(i).transpose();
    if (ca.dot(n) > 0.0) inside = false;
  }
  if (inside) {
    r->setZero();
    return false;
  }
  double best = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0; i < k; ++i) {
    const Eigen::Vector2d ab = poly.row((i + 1) % k) - poly.row(i);
    const double ab2 = ab.squaredNorm();
    const Eigen::Vector2d ca = Eigen::Vector2d(x, y) - poly.row(i).transpose();
    const double t = std::clamp(ca.dot(ab) / ab2, 0.0, 1.0);
    const Eigen::Vector2d ri = ca - t * ab;
    const double d2 = ri.squaredNorm();
    if (d2 < best) {
      best = d2;
      *r = ri;
      if (t == 0.0 || t == 1.0) {
        D->setIdentity();
      } else {
        const Eigen::Vector2d n = Eigen::Vector2d(ab.y(), -ab.x()) / std::sqrt(ab2);
        *D = n * n.transpose();
      }
    }
  }
  return true;
}

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("C++ projector: " + what);
}

}  // namespace

Projector::Projector(pinocchio::Model model, ProjectorSpec spec)
    : model_(std::move(model)), data_(model_), com_data_(model_), spec_(std::move(spec)) {
  const int nq = model_.nq, nv = model_.nv, nj = model_.njoints;
  auto joint_ok = [nj](int j) { return j >= 0 && j < nj; };
  int offset = 0;
  int level = -1;
  for (size_t c = 0; c < spec_.implicit.size(); ++c) {
    const ImplicitSpec& s = spec_.implicit[c];
    int rows = 0;
    switch (s.kind) {
      case ImplicitSpec::Kind::kRelative:
        Require(joint_ok(s.joint1) && joint_ok(s.joint2),
                "relative transformation joint out of the model");
        Require(s.mask.any(), "a mask selects at least one row");
        rows = static_cast<int>(s.mask.count());
        break;
      case ImplicitSpec::Kind::kPlacement:
        Require(s.placement >= 0 && s.placement < static_cast<int>(spec_.placements.size()),
                "placement index out of range");
        rows = 5;
        break;
      case ImplicitSpec::Kind::kComplement:
        Require(s.placement >= 0 && s.placement < static_cast<int>(spec_.placements.size()),
                "placement index out of range");
        rows = 3;
        break;
      case ImplicitSpec::Kind::kLocked:
        Require(s.nq == 1 || s.nq == 7, "implicit locked joints are 1-dof or free-flyers");
        Require(s.idx_q >= 0 && s.idx_q + s.nq <= nq && s.idx_v >= 0 &&
                    s.idx_v + (s.nq == 7 ? 6 : 1) <= nv,
                "implicit locked joint indices out of the configuration");
        rows = s.nq == 7 ? 6 : 1;
        break;
      case ImplicitSpec::Kind::kCom:
        Require(joint_ok(s.joint1), "centre of mass frame joint out of the model");
        Require(s.mask.head<3>().any(), "a centre-of-mass mask selects at least one of x y z");
        rows = static_cast<int>(s.mask.head<3>().count());
        break;
    }
    Require(s.level >= level, "implicit constraints must come in level order");
    if (s.level != level) {
      level = s.level;
      level_begin_.push_back(static_cast<int>(c));
      level_rows_.push_back(0);
    }
    level_rows_.back() += rows;
    sizes_.push_back(rows);
    rhs_offset_.push_back(offset);
    offset += rows;
  }
  level_begin_.push_back(static_cast<int>(spec_.implicit.size()));
  size_ = offset;
  for (size_t i = 0; i < spec_.locked_idx_q.size(); ++i) {
    Require(spec_.locked_idx_q[i] >= 0 && spec_.locked_idx_q[i] + spec_.locked_nq[i] <= nq,
            "locked joint index out of the configuration");
    locked_value_offset_.push_back(offset);
    offset += spec_.locked_nq[i];
  }
  for (const ImplicitSpec& s : spec_.implicit) {
    implicit_value_offset_.push_back(s.kind == ImplicitSpec::Kind::kLocked ? offset : -1);
    if (s.kind == ImplicitSpec::Kind::kLocked) offset += s.nq;
  }
  rhs_size_ = offset;
  Require(spec_.locked_nq.size() == spec_.locked_idx_q.size(),
          "locked_nq and locked_idx_q differ in size");
  const size_t nrel = spec_.relative_idx_q.size();
  Require(spec_.relative_parent.size() == nrel && spec_.relative_output.size() == nrel &&
              spec_.relative_M_PO.size() == nrel,
          "relative explicit constraint lists differ in size");
  for (size_t i = 0; i < nrel; ++i) {
    Require(joint_ok(spec_.relative_parent[i]) && joint_ok(spec_.relative_output[i]) &&
                spec_.relative_idx_q[i] >= 0 && spec_.relative_idx_q[i] + 7 <= nq,
            "relative explicit constraint index out of the model");
    Ad_OP_.push_back(spec_.relative_M_PO[i].inverse().toActionMatrix());
  }
  for (PlacementSpec& p : spec_.placements) {
    const size_t n = p.joint_e.size();
    Require(n > 0 && p.joint_o.size() == n && p.M_env.size() == n && p.M_obj.size() == n &&
                p.polygons.size() == n,
            "a placement needs as many environment / object frames and polygons as pairs");
    for (size_t i = 0; i < n; ++i) {
      Require(joint_ok(p.joint_e[i]) && joint_ok(p.joint_o[i]), "placement joint out of the model");
      Require(p.polygons[i].rows() >= 3, "a contact polygon has >= 3 vertices");
    }
  }
  for (int k : spec_.free_idx) Require(k >= 0 && k < nv, "free index out of the velocity space");
  for (int k : spec_.bounded_idx_q)
    Require(k >= 0 && k < nq, "bounded index out of the configuration");
  Require(spec_.lower.size() == static_cast<Eigen::Index>(spec_.bounded_idx_q.size()) &&
              spec_.upper.size() == spec_.lower.size(),
          "lower / upper must have one entry per bounded index");
  Require(spec_.sat_q.size() == spec_.sat_k.size() &&
              spec_.sat_lo.size() == static_cast<Eigen::Index>(spec_.sat_k.size()) &&
              spec_.sat_hi.size() == spec_.sat_lo.size(),
          "saturation lists differ in size");
  for (size_t i = 0; i < spec_.sat_k.size(); ++i)
    Require(spec_.sat_k[i] >= 0 && spec_.sat_k[i] < static_cast<int>(spec_.free_idx.size()) &&
                spec_.sat_q[i] >= 0 && spec_.sat_q[i] < nq,
            "saturation index out of range");
  is_static_.assign(nj, 0);
  for (int j : spec_.static_joints) {
    Require(joint_ok(j), "static joint out of the model");
    is_static_[j] = 1;
  }
  is_root_ff_.assign(nj, 0);
  for (int j = 1; j < nj; ++j)
    is_root_ff_[j] = model_.joints[j].nq() == 7 && model_.parents[j] == 0 ? 1 : 0;
  jac_.assign(nj, Matrix6x::Zero(6, nv));
  jac_valid_.assign(nj, 0);
  for (int j = 1; j < nj; ++j)
    if (is_root_ff_[j] && !is_static_[j])
      jac_[j].middleCols<6>(model_.joints[j].idx_v()).setIdentity();
  all_free_ = static_cast<int>(spec_.free_idx.size()) == nv;
  dv_ = Eigen::VectorXd::Zero(nv);
  rhs_ = Eigen::VectorXd::Zero(rhs_size_);
  pair_.assign(spec_.placements.size(), 0);
  const size_t nlevels = level_rows_.size();
  errors_.resize(nlevels);
  jacobians_.resize(nlevels);
  J6_.resize(6, nv);
  Jtmp_.resize(6, nv);
}

void Projector::SetRhs(const Eigen::VectorXd& rhs, const std::vector<int>& pairs) {
  if (rhs.size() != rhs_size_)
    throw std::invalid_argument("C++ projector: rhs has " + std::to_string(rhs.size()) +
                                " entries, expected " + std::to_string(rhs_size_));
  if (pairs.size() != spec_.placements.size())
    throw std::invalid_argument("C++ projector: one surface pair per placement expected");
  for (size_t i = 0; i < pairs.size(); ++i)
    if (pairs[i] < 0 || pairs[i] >= static_cast<int>(spec_.placements[i].joint_e.size()))
      throw std::invalid_argument("C++ projector: surface pair index out of range");
  rhs_ = rhs;
  pair_ = pairs;
}

void Projector::ApplyExplicit(Eigen::Ref<Eigen::VectorXd> q) {
  for (size_t i = 0; i < spec_.locked_idx_q.size(); ++i)
    q.segment(spec_.locked_idx_q[i], spec_.locked_nq[i]) =
        rhs_.segment(locked_value_offset_[i], spec_.locked_nq[i]);
  if (!spec_.relative_idx_q.empty()) {
    pinocchio::forwardKinematics(model_, data_, q);
    for (size_t i = 0; i < spec_.relative_idx_q.size(); ++i)
      WritePose(data_.oMi[spec_.relative_parent[i]] * spec_.relative_M_PO[i], q,
                spec_.relative_idx_q[i]);
  }
}

void Projector::UpdateAndSubstitute(Eigen::Ref<Eigen::VectorXd> q) {
  // Forward kinematics + joint Jacobians with the explicit outputs substituted; leaf
  // free-flyer outputs are patched after one pass (projector._update_and_substitute).
  if (!spec_.relative_idx_q.empty() && spec_.patchable) {
    pinocchio::computeJointJacobians(model_, data_, q);
    for (size_t i = 0; i < spec_.relative_idx_q.size(); ++i) {
      const pinocchio::SE3 X = data_.oMi[spec_.relative_parent[i]] * spec_.relative_M_PO[i];
      WritePose(X, q, spec_.relative_idx_q[i]);
      data_.oMi[spec_.relative_output[i]] = X;
    }
  } else {
    ApplyExplicit(q);
    pinocchio::computeJointJacobians(model_, data_, q);
  }
  q_cur_ = q;
  std::fill(jac_valid_.begin(), jac_valid_.end(), 0);
  com_valid_ = com_jacobian_valid_ = false;
}

const Eigen::Vector3d& Projector::Com() {
  if (!com_valid_) {
    pinocchio::centerOfMass(model_, com_data_, q_cur_, false);
    com_valid_ = true;
  }
  return com_data_.com[0];
}

const Eigen::Matrix3Xd& Projector::ComJacobian() {
  if (!com_jacobian_valid_) {
    pinocchio::jacobianCenterOfMass(model_, com_data_, q_cur_, false);
    com_valid_ = com_jacobian_valid_ = true;
  }
  return com_data_.Jcom;
}

const Matrix6x& Projector::JointJacobian(int joint) {
  // LOCAL joint Jacobian; 0 for the universe and static joints, the constant [0 I6 0] of a
  // free-flyer under the universe (valid even after its pose was patched).
  if (joint == 0 || is_static_[joint] || is_root_ff_[joint] || jac_valid_[joint])
    return jac_[joint];
  jac_[joint].setZero();
  pinocchio::getJointJacobian(model_, data_, static_cast<pinocchio::JointIndex>(joint),
                              pinocchio::LOCAL, jac_[joint]);
  jac_valid_[joint] = 1;
  return jac_[joint];
}

void Projector::RelativePose(int joint1, const pinocchio::SE3& M1, int joint2,
                             const pinocchio::SE3& M2, Relative* out) const {
  // M = (oMi1 M1)^-1 X2, X2 = oMi2 M2; value [p, log3 R] (constraints.RelativeTransformation).
  out->oMi1 = data_.oMi[joint1];
  out->X2 = data_.oMi[joint2] * M2;
  out->M = (out->oMi1 * M1).actInv(out->X2);
  out->v6.head<3>() = out->M.translation();
  out->v6.tail<3>() = pinocchio::log3(out->M.rotation());
}

void Projector::RelativeJacobian(int joint1, int joint2, const pinocchio::SE3& M2,
                                 const Relative& rel, Matrix6x* J) {
  // Body twist of M in F2: nu = Ad(M2^-1) J_2 - Ad(X2^-1 oMi1) J_1; dp = R nu_lin,
  // d log3(R) = Jlog3(R) nu_ang.
  const int nv = model_.nv;
  Matrix6x& nu = J6_;
  bool any = false;
  if (!is_static_[joint2]) {
    nu.noalias() = M2.inverse().toActionMatrix() * JointJacobian(joint2);
    any = true;
  }
  if (joint1 != 0 && !is_static_[joint1]) {
    const pinocchio::SE3::ActionMatrixType Ad = rel.X2.actInv(rel.oMi1).toActionMatrix();
    if (any) {
      nu.noalias() -= Ad * JointJacobian(joint1);
    } else {
      nu.noalias() = -(Ad * JointJacobian(joint1));
      any = true;
    }
  }
  J->resize(6, nv);
  if (!any) {
    J->setZero();
    return;
  }
  const Eigen::Matrix3d& R = rel.M.rotation();
  Eigen::Matrix3d Jlog;
  pinocchio::Jlog3(R, Jlog);
  J->topRows<3>().noalias() = R * nu.topRows<3>();
  J->bottomRows<3>().noalias() = Jlog * nu.bottomRows<3>();
}

void Projector::SelectPairs() {
  // A placement not pinned by its complement takes the surface pair nearest to being
  // satisfied (constraints.Placement.select_pair): |p_z - margin| + 0.3 |log3(R)_xy|.
  Relative rel;
  for (size_t k = 0; k < spec_.placements.size(); ++k) {
    const PlacementSpec& p = spec_.placements[k];
    if (!p.select || p.joint_e.size() < 2) continue;
    int best = 0;
    double best_cost = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < p.joint_e.size(); ++i) {
      RelativePose(p.joint_e[i], p.M_env[i], p.joint_o[i], p.M_obj[i], &rel);
      const double cost =
          std::abs(rel.M.translation()[2] - p.margin) + 0.3 * rel.v6.segment<2>(3).norm();
      if (cost < best_cost) {
        best = static_cast<int>(i);
        best_cost = cost;
      }
    }
    pair_[k] = best;
  }
}

void Projector::Errors(int level, Eigen::VectorXd* e) {
  e->resize(level_rows_[level]);
  int row = 0;
  Relative rel;
  for (int c = level_begin_[level]; c < level_begin_[level + 1]; ++c) {
    const ImplicitSpec& s = spec_.implicit[c];
    const auto rhs = rhs_.segment(rhs_offset_[c], sizes_[c]);
    switch (s.kind) {
      case ImplicitSpec::Kind::kRelative: {
        RelativePose(s.joint1, s.M1, s.joint2, s.M2, &rel);
        for (int i = 0, k = 0; i < 6; ++i) {
          if (!s.mask[i]) continue;
          (*e)[row + k] = rel.v6[i] - rhs[k];
          ++k;
        }
        break;
      }
      case ImplicitSpec::Kind::kPlacement: {
        const PlacementSpec& p = spec_.placements[s.placement];
        const int pr = pair_[s.placement];
        RelativePose(p.joint_e[pr], p.M_env[pr], p.joint_o[pr], p.M_obj[pr], &rel);
        for (int i = 0; i < 3; ++i) (*e)[row + i] = rel.v6[kPlacementRows[i]] - rhs[i];
        Eigen::Vector2d r;
        Eigen::Matrix2d D;
        PolygonOffset(p.polygons[pr], rel.v6[0], rel.v6[1], &r, &D);
        (*e)[row + 3] = r[0] - rhs[3];
        (*e)[row + 4] = r[1] - rhs[4];
        break;
      }
      case ImplicitSpec::Kind::kComplement: {
        const PlacementSpec& p = spec_.placements[s.placement];
        const int pr = pair_[s.placement];
        RelativePose(p.joint_e[pr], p.M_env[pr], p.joint_o[pr], p.M_obj[pr], &rel);
        for (int i = 0; i < 3; ++i) (*e)[row + i] = rel.v6[kComplementRows[i]] - rhs[i];
        (*e)[row + 2] = PyMod((*e)[row + 2] + M_PI, 2 * M_PI) - M_PI;
        break;
      }
      case ImplicitSpec::Kind::kLocked: {
        // e = log(q_locked^-1 q_joint) on the joint's tangent space.
        const int off = implicit_value_offset_[c];
        if (s.nq == 7) {
          const pinocchio::SE3 M = ReadPose(rhs_, off).actInv(ReadPose(q_cur_, s.idx_q));
          e->segment<6>(row) = pinocchio::log6(M).toVector() - rhs;
        } else {
          (*e)[row] = q_cur_[s.idx_q] - rhs_[off] - rhs[0];
        }
        break;
      }
      case ImplicitSpec::Kind::kCom: {
        const pinocchio::SE3 X_WF = data_.oMi[s.joint1] * s.M1;
        const Eigen::Vector3d c_F = X_WF.actInv(Com());
        for (int i = 0, k = 0; i < 3; ++i) {
          if (!s.mask[i]) continue;
          (*e)[row + k] = c_F[i] - rhs[k];
          ++k;
        }
        break;
      }
    }
    row += sizes_[c];
  }
}

void Projector::Jacobians(int level, Eigen::MatrixXd* Jout) {
  // Stacked Jacobians of one level (rows x nv), then the chain rule through the substituted
  // objects: J += J_O Ad_OP J_parent (J_red = J_free + J_out Ad J_parent), free columns kept.
  const int nv = model_.nv;
  Eigen::MatrixXd& J = jacobians_[level];
  J.resize(level_rows_[level], nv);
  int row = 0;
  Relative rel;
  Matrix6x J6;
  for (int c = level_begin_[level]; c < level_begin_[level + 1]; ++c) {
    const ImplicitSpec& s = spec_.implicit[c];
    switch (s.kind) {
      case ImplicitSpec::Kind::kRelative: {
        RelativePose(s.joint1, s.M1, s.joint2, s.M2, &rel);
        RelativeJacobian(s.joint1, s.joint2, s.M2, rel, &J6);
        for (int i = 0, k = 0; i < 6; ++i)
          if (s.mask[i]) J.row(row + k++) = J6.row(i);
        break;
      }
      case ImplicitSpec::Kind::kPlacement: {
        const PlacementSpec& p = spec_.placements[s.placement];
        const int pr = pair_[s.placement];
        RelativePose(p.joint_e[pr], p.M_env[pr], p.joint_o[pr], p.M_obj[pr], &rel);
        RelativeJacobian(p.joint_e[pr], p.joint_o[pr], p.M_obj[pr], rel, &J6);
        for (int i = 0; i < 3; ++i) J.row(row + i) = J6.row(kPlacementRows[i]);
        Eigen::Vector2d r;
        Eigen::Matrix2d D;
        if (PolygonOffset(p.polygons[pr], rel.v6[0], rel.v6[1], &r, &D))
          J.middleRows<2>(row + 3).noalias() = D * J6.topRows<2>();
        else
          J.middleRows<2>(row + 3).setZero();
        break;
      }
      case ImplicitSpec::Kind::kComplement: {
        const PlacementSpec& p = spec_.placements[s.placement];
        const int pr = pair_[s.placement];
        RelativePose(p.joint_e[pr], p.M_env[pr], p.joint_o[pr], p.M_obj[pr], &rel);
        RelativeJacobian(p.joint_e[pr], p.joint_o[pr], p.M_obj[pr], rel, &J6);
        for (int i = 0; i < 3; ++i) J.row(row + i) = J6.row(kComplementRows[i]);
        break;
      }
      case ImplicitSpec::Kind::kLocked: {
        J.middleRows(row, sizes_[c]).setZero();
        if (s.nq == 7) {
          const pinocchio::SE3 M =
              ReadPose(rhs_, implicit_value_offset_[c]).actInv(ReadPose(q_cur_, s.idx_q));
          Eigen::Matrix<double, 6, 6> Jlog;
          pinocchio::Jlog6(M, Jlog);
          J.block<6, 6>(row, s.idx_v) = Jlog;
        } else {
          J(row, s.idx_v) = 1.0;
        }
        break;
      }
      case ImplicitSpec::Kind::kCom: {
        // c_F = R^T (c - p): d c_F = R^T (J_c - J_p) dq - [w_F]x c_F, with J_F LOCAL in F
        // (linear part R^T J_p, angular part w_F): J = R^T J_c - J_F,lin + [c_F]x J_F,ang.
        const pinocchio::SE3 X_WF = data_.oMi[s.joint1] * s.M1;
        const Eigen::Vector3d c_F = X_WF.actInv(Com());
        Eigen::Matrix3Xd Jc = X_WF.rotation().transpose() * ComJacobian();
        if (s.joint1 != 0) {
          J6.noalias() = s.M1.inverse().toActionMatrix() * JointJacobian(s.joint1);
          Jc -= J6.topRows<3>();
          for (int col = 0; col < nv; ++col) Jc.col(col) += c_F.cross(J6.col(col).tail<3>());
        }
        for (int i = 0, k = 0; i < 3; ++i)
          if (s.mask[i]) J.row(row + k++) = Jc.row(i);
        break;
      }
    }
    row += sizes_[c];
  }
  if (Jout != nullptr) {  // raw stacked Jacobian (tests)
    *Jout = J;
    return;
  }
  for (size_t i = 0; i < spec_.relative_idx_q.size(); ++i) {
    const int iv = model_.joints[spec_.relative_output[i]].idx_v();
    const auto Jo = J.middleCols<6>(iv);
    if ((Jo.array() != 0.0).any()) {
      Jtmp_.noalias() = Ad_OP_[i] * JointJacobian(spec_.relative_parent[i]);
      const Eigen::MatrixXd add = Jo * Jtmp_;
      J += add;
    }
  }
  if (!all_free_) {
    Eigen::MatrixXd Jr(J.rows(), static_cast<Eigen::Index>(spec_.free_idx.size()));
    for (size_t k = 0; k < spec_.free_idx.size(); ++k) Jr.col(k) = J.col(spec_.free_idx[k]);
    J.swap(Jr);
  }
}

namespace {

// x = (A A^T + lambda I)^-1 r by Cholesky; the minimum-norm least-squares solution (numpy's
// lstsq, relative cut-off eps max(m, n)) when Cholesky fails.
Eigen::VectorXd DampedSolve(const Eigen::MatrixXd& A, const Eigen::VectorXd& r, double damping) {
  Eigen::MatrixXd AAt = A * A.transpose();
  AAt.diagonal().array() += damping;
  Eigen::LLT<Eigen::MatrixXd> llt(AAt);
  if (llt.info() == Eigen::Success) return llt.solve(r);
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(AAt, Eigen::ComputeThinU | Eigen::ComputeThinV);
  svd.setThreshold(std::numeric_limits<double>::epsilon() * static_cast<double>(AAt.rows()));
  return svd.solve(r);
}

}  // namespace

void Projector::Descent(const Eigen::Ref<const Eigen::VectorXd>& q, Eigen::VectorXd* step) {
  // Newton step on the free variables, level by level in the null space of the previous ones,
  // saturated joints removed (projector.Projector._descent / _solve).
  const int nlevels = static_cast<int>(level_rows_.size());
  for (int L = 0; L < nlevels; ++L) Jacobians(L, nullptr);
  std::vector<int> sat;
  if (!spec_.sat_k.empty() && clipped_) {
    // HPP's saturation: a joint on a bound whose descent direction -J^T e points outward is
    // removed from the problem (one solve, no retry).
    Eigen::VectorXd d;
    bool computed = false;
    for (size_t i = 0; i < spec_.sat_k.size(); ++i) {
      const double qs = q[spec_.sat_q[i]];
      const bool at_lo = qs <= spec_.sat_lo[i], at_hi = qs >= spec_.sat_hi[i];
      if (!at_lo && !at_hi) continue;
      if (!computed) {
        d = -(jacobians_[0].transpose() * errors_[0]);
        computed = true;
      }
      const double di = d[spec_.sat_k[i]];
      if ((at_lo && di < 0) || (at_hi && di > 0)) sat.push_back(spec_.sat_k[i]);
    }
  }
  const Eigen::Index n = static_cast<Eigen::Index>(spec_.free_idx.size());
  if (nlevels == 1) {
    Eigen::MatrixXd& J = jacobians_[0];
    for (int k : sat) J.col(k).setZero();
    *step = -(J.transpose() * DampedSolve(J, errors_[0], spec_.damping));
    return;
  }
  step->setZero(n);
  Eigen::MatrixXd N, A;
  bool have_N = false;
  for (int L = 0; L < nlevels; ++L) {
    Eigen::MatrixXd& J = jacobians_[L];
    for (int k : sat) J.col(k).setZero();
    Eigen::VectorXd r = -errors_[L];
    if (have_N) {
      r -= J * (*step);
      A = J * N;
    } else {
      A = J;
    }
    *step += A.transpose() * DampedSolve(A, r, spec_.damping);
    // Null-space projector of this level: P = pinv(A) A with numpy's relative cut-off 1e-8.
    Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeThinV);
    const Eigen::VectorXd& sv = svd.singularValues();
    const double cutoff = sv.size() ? 1e-8 * sv.maxCoeff() : 0.0;
    Eigen::MatrixXd P = Eigen::MatrixXd::Zero(n, n);
    for (Eigen::Index i = 0; i < sv.size(); ++i)
      if (sv[i] > cutoff) P.noalias() += svd.matrixV().col(i) * svd.matrixV().col(i).transpose();
    const Eigen::MatrixXd IP = Eigen::MatrixXd::Identity(n, n) - P;
    N = have_N ? Eigen::MatrixXd(N * IP) : IP;
    have_N = true;
  }
}

ProjectionOutcome Projector::Project(Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
                                     std::vector<int>* pairs, double error_threshold,
                                     int max_iterations) {
  if (q.size() != model_.nq)
    throw std::invalid_argument("C++ projector: q has " + std::to_string(q.size()) +
                                " entries, expected " + std::to_string(model_.nq));
  if (!(error_threshold > 0) || max_iterations < 1)
    throw std::invalid_argument(
        "C++ projector: error_threshold must be > 0 and max_iterations >= 1");
  SetRhs(rhs, *pairs);
  ProjectionOutcome out;
  if (spec_.implicit.empty()) {
    ApplyExplicit(q);
    return out;
  }
  const int nlevels = static_cast<int>(level_rows_.size());
  auto errors_norm2 = [&]() {
    double n2 = 0.0;
    for (int L = 0; L < nlevels; ++L) {
      Errors(L, &errors_[L]);
      n2 += errors_[L].squaredNorm();
    }
    return n2;
  };
  for (size_t i = 0; i < spec_.locked_idx_q.size(); ++i)
    q.segment(spec_.locked_idx_q[i], spec_.locked_nq[i]) =
        rhs_.segment(locked_value_offset_[i], spec_.locked_nq[i]);
  UpdateAndSubstitute(q);
  SelectPairs();
  *pairs = pair_;
  const double eps2 = error_threshold * error_threshold;
  double norm2 = errors_norm2();
  if (!std::isfinite(norm2)) return {ProjectionStatus::kNotFinite, 0, norm2};
  const LineSearchSpec& ls = spec_.line_search;
  double alpha = ls.alpha0;
  int not_decreasing = 0;
  const double max_step2 = ls.max_step * ls.max_step;
  clipped_ = true;  // unknown at the start: check the bounds once
  int it = 0;
  Eigen::VectorXd qnext(model_.nq);
  while (norm2 > eps2) {
    if (it >= max_iterations) return {ProjectionStatus::kMaxIterations, it, std::sqrt(norm2)};
    Descent(q, &step_);
    const double n2 = step_.squaredNorm();
    if (n2 < 1e-20) return {ProjectionStatus::kLocalMinimum, it, std::sqrt(norm2)};
    // Trust region: far from the manifold, the linearisation is wrong anyway.
    if (n2 > max_step2) step_ *= ls.max_step / std::sqrt(n2);
    double a = 1.0;
    if (ls.kind == LineSearchSpec::Kind::kFixedSequence) {
      a = alpha;  // Algorithm 1: alpha <- alpha_max - K (alpha_max - alpha)
      alpha = ls.alpha_max - ls.K * (ls.alpha_max - alpha);
    } else if (ls.kind == LineSearchSpec::Kind::kErrorNorm) {
      a = ErrorNormAlpha(norm2 / eps2, ls.alpha_min);
    }
    if (a != 1.0) step_ *= a;
    if (all_free_) {
      pinocchio::integrate(model_, q, step_, qnext);
    } else {
      for (size_t k = 0; k < spec_.free_idx.size(); ++k) dv_[spec_.free_idx[k]] = step_[k];
      pinocchio::integrate(model_, q, dv_, qnext);
    }
    q = qnext;
    clipped_ = false;
    for (size_t k = 0; k < spec_.bounded_idx_q.size(); ++k) {
      double& v = q[spec_.bounded_idx_q[k]];
      if (v < spec_.lower[k] || v > spec_.upper[k]) clipped_ = true;
    }
    if (clipped_)
      for (size_t k = 0; k < spec_.bounded_idx_q.size(); ++k) {
        double& v = q[spec_.bounded_idx_q[k]];
        v = std::min(std::max(v, spec_.lower[k]), spec_.upper[k]);  // numpy.clip
      }
    UpdateAndSubstitute(q);
    const double new_norm2 = errors_norm2();
    if (!std::isfinite(new_norm2)) return {ProjectionStatus::kNotFinite, it, new_norm2};
    ++it;
    not_decreasing = new_norm2 >= norm2 ? not_decreasing + 1 : 0;
    norm2 = new_norm2;
    if (not_decreasing >= 3 && norm2 > eps2)
      return {ProjectionStatus::kNotDecreasing, it, std::sqrt(norm2)};
  }
  return {ProjectionStatus::kSuccess, it, std::sqrt(norm2)};
}

bool Projector::IsSatisfied(const Eigen::Ref<const Eigen::VectorXd>& q, const Eigen::VectorXd& rhs,
                            std::vector<int>* pairs, double threshold) {
  if (q.size() != model_.nq)
    throw std::invalid_argument("C++ projector: q has " + std::to_string(q.size()) +
                                " entries, expected " + std::to_string(model_.nq));
  SetRhs(rhs, *pairs);
  double err = 0.0;
  for (size_t i = 0; i < spec_.locked_idx_q.size(); ++i) {
    const int iq = spec_.locked_idx_q[i], n = spec_.locked_nq[i], off = locked_value_offset_[i];
    if (n == 7) {  // translation distance + quaternion distance up to sign (q and -q: one rotation)
      const auto a = q.segment<4>(iq + 3);
      const auto v = rhs_.segment<4>(off + 3);
      err = std::max(err, (q.segment<3>(iq) - rhs_.segment<3>(off)).norm() +
                              std::min((a - v).norm(), (a + v).norm()));
    } else {
      err = std::max(err, (q.segment(iq, n) - rhs_.segment(off, n)).norm());
    }
  }
  if (!spec_.relative_idx_q.empty()) {
    pinocchio::forwardKinematics(model_, data_, q);
    for (size_t i = 0; i < spec_.relative_idx_q.size(); ++i) {
      const pinocchio::SE3 X = ReadPose(q, spec_.relative_idx_q[i]);
      const pinocchio::SE3 pose = data_.oMi[spec_.relative_parent[i]] * spec_.relative_M_PO[i];
      err = std::max(err, pinocchio::log6(pose.actInv(X)).toVector().norm());
    }
  }
  if (err > threshold) return false;
  if (spec_.implicit.empty()) return true;
  pinocchio::forwardKinematics(model_, data_, q);
  q_cur_ = q;
  std::fill(jac_valid_.begin(), jac_valid_.end(), 0);  // data_.J is not that of q
  com_valid_ = com_jacobian_valid_ = false;
  SelectPairs();
  *pairs = pair_;
  double n2 = 0.0;
  for (int L = 0; L < static_cast<int>(level_rows_.size()); ++L) {
    Errors(L, &errors_[L]);
    n2 += errors_[L].squaredNorm();
  }
  return n2 <= threshold * threshold;
}

Eigen::VectorXd Projector::Error(Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
                                 std::vector<int>* pairs) {
  if (q.size() != model_.nq) throw std::invalid_argument("C++ projector: q must have nq entries");
  SetRhs(rhs, *pairs);
  pinocchio::computeJointJacobians(model_, data_, q);
  q_cur_ = q;
  std::fill(jac_valid_.begin(), jac_valid_.end(), 0);
  com_valid_ = com_jacobian_valid_ = false;
  SelectPairs();
  *pairs = pair_;
  Eigen::VectorXd out(size_);
  for (int L = 0, row = 0; L < static_cast<int>(level_rows_.size()); ++L) {
    Errors(L, &errors_[L]);
    out.segment(row, level_rows_[L]) = errors_[L];
    row += level_rows_[L];
  }
  return out;
}

Eigen::MatrixXd Projector::Jacobian(Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
                                    std::vector<int>* pairs) {
  Error(q, rhs, pairs);
  Eigen::MatrixXd out(size_, model_.nv);
  Eigen::MatrixXd J;
  for (int L = 0, row = 0; L < static_cast<int>(level_rows_.size()); ++L) {
    Jacobians(L, &J);
    out.middleRows(row, level_rows_[L]) = J;
    row += level_rows_[L];
  }
  return out;
}

}  // namespace marionette::planning
