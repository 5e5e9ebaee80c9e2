#include "marionette/sot/hierarchy.h"

#include <Eigen/Householder>
#include <algorithm>
#include <cmath>


#include <eiquadprog/eiquadprog-fast.hpp>

namespace marionette::sot {

namespace {
}  // namespace

Hierarchy::Hierarchy(int nv, std::vector<std::vector<TaskShape>> levels, HierarchyOptions options)
    : nv_(nv), levels_(std::move(levels)), options_(options) {
  if (nv_ < 1) throw SotError("Hierarchy: nv must be >= 1, got " + std::to_string(nv_));
  if (!(options_.rank_tolerance > 0.0) || options_.damping < 0.0 ||
      !(options_.damping_threshold > 0.0) || !(options_.constraint_tolerance >= 0.0) ||
      options_.qp_max_iterations < 1) {
    throw SotError("Hierarchy: invalid options (tolerances > 0, damping >= 0, iterations >= 1)");
  }
  for (size_t l = 0; l < levels_.size(); ++l) {
    int eq = 0, in = 0;
    for (const TaskShape& t : levels_[l]) {
      if (t.rows < 1) throw SotError("Hierarchy: a task of level " + std::to_string(l) + " has no row");
      if (!t.unit_columns.empty()) {
        if (static_cast<int>(t.unit_columns.size()) != t.rows) {
          throw SotError("Hierarchy: unit_columns size differs from the task's rows");
        }
        for (int c : t.unit_columns) {
          if (c < 0 || c >= nv_) throw SotError("Hierarchy: unit column out of range");
        }
      }
      (t.inequality ? in : eq) += t.rows;
      total_rows_ += t.rows;
      ++num_tasks_;
    }
    max_equality_rows_ = std::max(max_equality_rows_, eq);
    max_inequality_rows_ = std::max(max_inequality_rows_, in);
    total_inequality_rows_ += in;
  }
}

struct HierarchyWorkspace::Impl {
  explicit Impl(const Hierarchy& h) {
    const int n = h.nv(), me = std::max(1, h.max_equality_rows()),
              mi = std::max(1, h.max_inequality_rows()), mc = std::max(1, h.total_inequality_rows());
    Z.resize(n, n);
    x.resize(n);
    x_old.resize(n);
    u.resize(n);
    A.resize(me, n);
    b.resize(me);
    a_col.resize(me);
    Mt.resize(n, me);
    hcoeffs.resize(me);
    norms.resize(me);
    perm.resize(me);
    c.resize(me);
    cperm.resize(me);
    y.resize(n);
    B.resize(me + n, n);
    d.resize(me + n);
    work.resize(2 * (n + me + mi));
    C.resize(mi, n);
    clo.resize(mi);
    chi.resize(mi);
    c_col.resize(mi);
    G.resize(mc, n);
    glo.resize(mc);
    ghi.resize(mc);
    g_col.resize(mc);
    int carried = 0;
    for (const auto& level : h.levels()) {
      int level_rows = 0;
      for (const TaskShape& t : level) level_rows += t.inequality ? t.rows : 0;
      auto qp = std::make_unique<LevelQp>();
      const int nz = n + level_rows, nc = 2 * (carried + level_rows);
      qp->H.resize(nz, nz);
      qp->g.resize(nz);
      qp->z.resize(nz);
      qp->row.resize(nz);
      qp->CI.resize(nc, nz);
      qp->ci0.resize(nc);
      qp->CE.resize(0, nz);
      qp->ce0.resize(0);
      qp->R1.resize(n, me);
      qp->solver.reset(nz, 0, nc);
      qp->solver.setMaxIter(h.options().qp_max_iterations);
      qps.push_back(std::move(qp));
      carried += level_rows;
    }
  }

  // Basis of the remaining freedom: columns [off, n) of Z (n x n).
  Eigen::MatrixXd Z;
  Eigen::VectorXd x, x_old, u;
  // Equality rows of the current level: A (m x n), b (m); a_col[i] >= 0 for a unit row.
  Eigen::MatrixXd A;
  Eigen::VectorXd b;
  std::vector<int> a_col;
  // QR of M^T = (A Z)^T (r x m): R above the diagonal, Householder vectors below.
  Eigen::MatrixXd Mt;
  Eigen::VectorXd hcoeffs, norms, c, cperm, y;
  std::vector<int> perm;
  // Second QR for rank-deficient or damped least squares: [R1^T; μ I] ((m + ρ) x ρ).
  Eigen::MatrixXd B;
  Eigen::VectorXd d, work;
  // Inequality rows of the current level.
  Eigen::MatrixXd C;
  Eigen::VectorXd clo, chi;
  std::vector<int> c_col;
  // Inequality rows carried from the levels above (bounds already shifted by their slacks).
  Eigen::MatrixXd G;
  Eigen::VectorXd glo, ghi;
  std::vector<int> g_col;
  int num_carried = 0;
  // One QP per level, sized for the worst case at construction so a solve allocates nothing:
  // variables ũ (nv, padded beyond r) and one slack per inequality row of the level;
  // constraints CI z + ci0 >= 0, two per carried or level inequality row (padding rows 0 z + 1).
  struct LevelQp {
    Eigen::MatrixXd H, CI, CE, R1;
    Eigen::VectorXd g, ci0, ce0, z, row;
    eiquadprog::solvers::EiquadprogFast solver;
  };
  std::vector<std::unique_ptr<LevelQp>> qps;
};

HierarchyWorkspace::HierarchyWorkspace(const Hierarchy& hierarchy)
    : impl_(std::make_unique<Impl>(hierarchy)) {
  report_.ranks.assign(hierarchy.num_levels(), 0);
  report_.qp_levels.assign(hierarchy.num_levels(), false);
  report_.dampings.assign(hierarchy.num_levels(), 0.0);
}
HierarchyWorkspace::~HierarchyWorkspace() = default;
HierarchyWorkspace::HierarchyWorkspace(HierarchyWorkspace&&) noexcept = default;

namespace {

using Impl = HierarchyWorkspace::Impl;

// Householder QR with column pivoting of mt (r x m): mt Π = Q R, Q = H_0 H_1 ... H_{ρ-1}.
// Stops when the largest remaining column norm is <= threshold (a row of A Z that is a
// combination of the others, or that higher levels already fixed, up to rounding). Returns ρ.
int PivotedQr(Eigen::Ref<Eigen::MatrixXd> mt, std::vector<int>& perm, Eigen::VectorXd& hcoeffs,
              Eigen::VectorXd& norms, Eigen::VectorXd& work, double threshold) {
  const int r = static_cast<int>(mt.rows()), m = static_cast<int>(mt.cols());
  for (int i = 0; i < m; ++i) perm[i] = i;
  const int steps = std::min(r, m);
  for (int j = 0; j < steps; ++j) {
    int p = j;
    for (int i = j; i < m; ++i) {
      norms[i] = mt.col(i).tail(r - j).squaredNorm();
      if (norms[i] > norms[p]) p = i;
    }
    const double pivot = std::sqrt(norms[p]);
    if (pivot <= threshold || pivot == 0.0) return j;
    if (p != j) {
      mt.col(j).swap(mt.col(p));
      std::swap(perm[j], perm[p]);
    }
    double tau, beta;
    mt.col(j).tail(r - j).makeHouseholderInPlace(tau, beta);
    mt(j, j) = beta;
    hcoeffs[j] = tau;
    if (j + 1 < m) {
      mt.bottomRightCorner(r - j, m - j - 1)
          .applyHouseholderOnTheLeft(mt.col(j).tail(r - j - 1), tau, work.data());
    }
  }
  return steps;
}

// Z_blk <- Z_blk H_0 ... H_{ρ-1}: its first ρ columns then span range(M^T), the others null(M).
void RotateBasis(Eigen::Ref<Eigen::MatrixXd> Z_blk, const Eigen::Ref<const Eigen::MatrixXd>& mt,
                 const Eigen::VectorXd& hcoeffs, int rho, Eigen::VectorXd& work) {
  const int r = static_cast<int>(Z_blk.cols());
  for (int j = 0; j < rho; ++j) {
    Z_blk.rightCols(r - j).applyHouseholderOnTheRight(mt.col(j).tail(r - j - 1), hcoeffs[j],
                                                      work.data());
  }
}

bool Inside(double value, double lo, double hi, double tol) {
  return value >= lo - tol && value <= hi + tol;
}

bool CarriedFeasible(const Impl& w, const Eigen::VectorXd& x, double tol) {
  for (int i = 0; i < w.num_carried; ++i) {
    const double value = w.g_col[i] >= 0 ? x[w.g_col[i]] : w.G.row(i).dot(x);
    if (!Inside(value, w.glo[i], w.ghi[i], tol)) return false;
  }
  return true;
}

double RowValue(const Impl& w, int i, const Eigen::VectorXd& x) {
  return w.c_col[i] >= 0 ? x[w.c_col[i]] : w.C.row(i).dot(x);
}

bool LevelFeasible(const Impl& w, int mi, const Eigen::VectorXd& x, double tol) {
  for (int i = 0; i < mi; ++i) {
    if (!Inside(RowValue(w, i, x), w.clo[i], w.chi[i], tol)) return false;
  }
  return true;
}

// Least squares min ||R1^T y - cperm||² + μ²||y||² with R1 = upper part of mt's first ρ rows
// (ρ x m). Plain triangular solve when full row rank and undamped.
void SolveLeastSquares(Impl& w, int m, int rho, double mu) {
  auto R1 = w.Mt.topLeftCorner(rho, m);
  if (rho == m && mu == 0.0) {
    w.y.head(rho) = w.cperm.head(rho);
    R1.leftCols(rho).triangularView<Eigen::Upper>().transpose().solveInPlace(w.y.head(rho));
    return;
  }
  const int mb = m + (mu > 0.0 ? rho : 0);
  auto B = w.B.topLeftCorner(mb, rho);
  B.topRows(m) = R1.triangularView<Eigen::Upper>().transpose();
  w.d.head(m) = w.cperm.head(m);
  if (mu > 0.0) {
    B.bottomRows(rho).setZero();
    B.bottomRows(rho).diagonal().setConstant(mu);
    w.d.segment(m, rho).setZero();
  }
  for (int j = 0; j < rho; ++j) {
    double tau, beta;
    B.col(j).tail(mb - j).makeHouseholderInPlace(tau, beta);
    B(j, j) = beta;
    if (j + 1 < rho) {
      B.bottomRightCorner(mb - j, rho - j - 1)
          .applyHouseholderOnTheLeft(B.col(j).tail(mb - j - 1), tau, w.work.data());
    }
    w.d.segment(j, mb - j).applyHouseholderOnTheLeft(B.col(j).tail(mb - j - 1), tau,
                                                     w.work.data());
  }
  w.y.head(rho) = w.d.head(rho);
  B.topLeftCorner(rho, rho).triangularView<Eigen::Upper>().solveInPlace(w.y.head(rho));
}

// One QP for a level whose unconstrained step violates an inequality: variables (ũ (r), s (mi))
// with v = x_old + Z_blk ũ. Objective ½||R1^T ũ_1 - cperm||² + ½||s||²; constraints: carried
// rows within their bounds, the level's rows within theirs up to s. Solved by eiquadprog's dual
// active-set method (Goldfarb–Idnani, TSID's QP): exact, and robust on the degenerate vertices
// met here (many velocity bounds active at the current point), where a proximal method (proxsuite)
// stalled or reported feasible problems infeasible. Returns false on failure.
bool SolveLevelQp(Impl& w, Impl::LevelQp& q, const Eigen::Ref<const Eigen::MatrixXd>& Z_blk,
                  int m, int rho, int mi, double mu, double regularization,
                  HierarchyReport* report) {
  const int r = static_cast<int>(Z_blk.cols()), n = static_cast<int>(Z_blk.rows());
  const int slack0 = n;  // slack variables follow the (padded) ũ
  q.H.setZero();
  q.g.setZero();
  // The level's objective directions ũ_1 (first ρ) are left exact: a regularization there
  // would bias the level's own optimum (feet drifting whenever bounds bind below them).
  q.H.diagonal().head(n).setConstant(std::max(regularization, 1e-12));
  q.H.diagonal().head(rho).setConstant(1e-12);
  q.H.diagonal().tail(q.H.rows() - n).setOnes();  // ½||s||² (and unused slacks)
  if (rho > 0) {
    // A Z_blk = [Π R1^T, 0] after the rotation, so ||A v - b||² = ||R1^T ũ_1 - cperm||².
    auto R1 = q.R1.topLeftCorner(rho, m);
    R1 = w.Mt.topLeftCorner(rho, m);
    R1.triangularView<Eigen::StrictlyLower>().setZero();
    q.H.topLeftCorner(rho, rho).noalias() += R1 * R1.transpose();
    q.H.diagonal().head(rho).array() += mu * mu;  // the same damping as the unconstrained step
    q.g.head(rho).noalias() = -R1 * w.cperm.head(m);
  }
  q.CI.setZero();
  q.ci0.setOnes();  // padding rows: 1 >= 0
  int row = 0;
  // lo <= a·z + value <= hi as  a·z + (value - lo) >= 0  and  -a·z + (hi - value) >= 0; the
  // bounds are widened to include the current point (value), which the QPs above may leave
  // outside by their rounding (~1e-15).
  auto add = [&](const auto& a, double value, double lo, double hi) {
    if (!std::isinf(lo)) {
      q.CI.row(row) = a;
      q.ci0[row] = std::max(value - lo, 0.0);
    }
    ++row;
    if (!std::isinf(hi)) {
      q.CI.row(row) = -a;
      q.ci0[row] = std::max(hi - value, 0.0);
    }
    ++row;
  };
  Eigen::Ref<Eigen::VectorXd> a = q.row;
  for (int i = 0; i < w.num_carried; ++i) {
    a.setZero();
    double value;
    if (w.g_col[i] >= 0) {
      a.head(r) = Z_blk.row(w.g_col[i]).transpose();
      value = w.x_old[w.g_col[i]];
    } else {
      a.head(r).noalias() = Z_blk.transpose() * w.G.row(i).transpose();
      value = w.G.row(i).dot(w.x_old);
    }
    if (a.head(r).squaredNorm() < 1e-24) {  // fixed by higher levels: nothing to decide
      row += 2;
      continue;
    }
    add(a.transpose(), value, w.glo[i], w.ghi[i]);
  }
  for (int i = 0; i < mi; ++i) {
    a.setZero();
    if (w.c_col[i] >= 0) {
      a.head(r) = Z_blk.row(w.c_col[i]).transpose();
    } else {
      a.head(r).noalias() = Z_blk.transpose() * w.C.row(i).transpose();
    }
    a[slack0 + i] = -1.0;
    // The level's own rows: the slack absorbs any violation, no widening.
    const double value = RowValue(w, i, w.x_old);
    if (!std::isinf(w.clo[i])) {
      q.CI.row(row) = a.transpose();
      q.ci0[row] = value - w.clo[i];
    }
    ++row;
    if (!std::isinf(w.chi[i])) {
      q.CI.row(row) = -a.transpose();
      q.ci0[row] = w.chi[i] - value;
    }
    ++row;
  }
  const auto status = q.solver.solve_quadprog(q.H, q.g, q.CE, q.ce0, q.CI, q.ci0, q.z);
  report->last_qp_status = static_cast<int>(status);
  report->last_qp_iterations = q.solver.getIteratios();
  if (status != eiquadprog::solvers::EIQUADPROG_FAST_OPTIMAL || !q.z.allFinite()) return false;
  w.x = w.x_old;
  w.x.noalias() += Z_blk * q.z.head(r);
  return true;
}

}  // namespace

void SolveHierarchy(const Hierarchy& hierarchy, const std::vector<const TaskTerms*>& tasks,
                    HierarchyWorkspace* workspace, Eigen::VectorXd* v,
                    const Eigen::VectorXd* target_offsets) {
  const int n = hierarchy.nv();
  if (static_cast<int>(tasks.size()) != hierarchy.num_tasks()) {
    throw SotError("SolveHierarchy: " + std::to_string(tasks.size()) + " tasks given, the hierarchy has " +
                   std::to_string(hierarchy.num_tasks()));
  }
  {
    int k = 0;
    for (const auto& level : hierarchy.levels()) {
      for (const TaskShape& shape : level) {
        const TaskTerms* t = tasks[k++];
        if (t == nullptr || t->jacobian.rows() != shape.rows || t->jacobian.cols() != n ||
            t->lower.size() != shape.rows || t->upper.size() != shape.rows ||
            t->inequality != shape.inequality) {
          throw SotError("SolveHierarchy: task " + std::to_string(k - 1) +
                         " does not match its shape in the hierarchy");
        }
      }
    }
  }
  if (target_offsets != nullptr && target_offsets->size() != hierarchy.total_rows()) {
    throw SotError("SolveHierarchy: target_offsets has " + std::to_string(target_offsets->size()) +
                   " rows, the tasks " + std::to_string(hierarchy.total_rows()));
  }
  Impl& w = *workspace->impl_;
  HierarchyReport& report = workspace->report_;
  const HierarchyOptions& options = hierarchy.options();
  const double tol = options.constraint_tolerance;
  report.num_qp = 0;
  report.qp_failures = 0;
  w.Z.setIdentity();
  w.x.setZero();
  w.num_carried = 0;
  int off = 0;         // Z's first free column
  int k = 0;           // task index
  int row = 0;         // first row of task k among all tasks' rows
  const int num_levels = hierarchy.num_levels();
  // Last level holding equality rows: no basis rotation is needed after it.
  int last_rotation_level = -1;
  for (int l = 0; l < num_levels; ++l) {
    for (const TaskShape& s : hierarchy.levels()[l]) {
      if (!s.inequality) last_rotation_level = l;
    }
  }
  for (int l = 0; l < num_levels; ++l) {
    // Gather the level's active rows.
    int m = 0, mi = 0;
    bool dense = false;
    double row_scale = 0.0;  // largest |row of A|: the rank threshold is relative to it
    for (const TaskShape& shape : hierarchy.levels()[l]) {
      const TaskTerms& t = *tasks[k++];
      const int first_row = row;
      row += shape.rows;
      if (!t.active) continue;
      if (t.inequality) {
        for (int i = 0; i < shape.rows; ++i, ++mi) {
          w.c_col[mi] = shape.unit_columns.empty() ? -1 : shape.unit_columns[i];
          if (w.c_col[mi] < 0) w.C.row(mi) = t.jacobian.row(i);
          w.clo[mi] = t.lower[i];
          w.chi[mi] = t.upper[i];
        }
      } else {
        for (int i = 0; i < shape.rows; ++i, ++m) {
          w.a_col[m] = shape.unit_columns.empty() ? -1 : shape.unit_columns[i];
          if (w.a_col[m] < 0) {
            w.A.row(m) = t.jacobian.row(i);
            row_scale = std::max(row_scale, w.A.row(m).squaredNorm());
            dense = true;
          } else {
            row_scale = std::max(row_scale, 1.0);
          }
          w.b[m] = t.lower[i] + (target_offsets ? (*target_offsets)[first_row + i] : 0.0);
        }
      }
    }
    const int r = n - off;
    report.ranks[l] = 0;
    report.qp_levels[l] = false;
    report.dampings[l] = 0.0;
    w.x_old = w.x;
    int rho = 0;
    bool rotated = false;
    auto Z_blk = w.Z.middleCols(off, r);
    if (m > 0 && r > 0) {
      auto mt = w.Mt.topLeftCorner(r, m);
      if (dense) {
        // Unit rows are filled as rows of the identity so one product serves all rows.
        for (int i = 0; i < m; ++i) {
          if (w.a_col[i] >= 0) {
            w.A.row(i).setZero();
            w.A(i, w.a_col[i]) = 1.0;
          }
        }
        if (off == 0) {
          mt = w.A.topRows(m).transpose();  // Z = I before the first equality level
        } else {
          mt.noalias() = Z_blk.transpose() * w.A.topRows(m).transpose();
        }
        w.c.head(m).noalias() = w.b.head(m) - w.A.topRows(m) * w.x;
      } else {
        for (int i = 0; i < m; ++i) {
          mt.col(i) = Z_blk.row(w.a_col[i]).transpose();
          w.c[i] = w.b[i] - w.x[w.a_col[i]];
        }
      }
      rho = PivotedQr(mt, w.perm, w.hcoeffs, w.norms, w.work,
                      options.rank_tolerance * std::sqrt(row_scale));
      for (int i = 0; i < m; ++i) w.cperm[i] = w.c[w.perm[i]];
      if (rho > 0) {
        double mu = 0.0;
        const double smallest = std::abs(w.Mt(rho - 1, rho - 1));
        if (options.damping > 0.0 && smallest < options.damping_threshold) {
          const double ratio = smallest / options.damping_threshold;
          mu = options.damping * std::sqrt(1.0 - ratio * ratio);
        }
        report.dampings[l] = mu;
        SolveLeastSquares(w, m, rho, mu);
        // u = Q [y; 0] (apply H_{ρ-1} first), v += Z u.
        w.u.head(r).setZero();
        w.u.head(rho) = w.y.head(rho);
        for (int j = rho - 1; j >= 0; --j) {
          w.u.segment(j, r - j).applyHouseholderOnTheLeft(w.Mt.col(j).segment(j + 1, r - j - 1),
                                                          w.hcoeffs[j], w.work.data());
        }
        w.x.noalias() += Z_blk * w.u.head(r);
      }
    }
    // The unconstrained step is the cascade's solution when it keeps every inequality.
    if (w.num_carried + mi > 0 &&
        !(CarriedFeasible(w, w.x, tol) && LevelFeasible(w, mi, w.x, tol))) {
      if (r > 0) {
        if (rho > 0) {
          RotateBasis(Z_blk, w.Mt.topLeftCorner(r, m), w.hcoeffs, rho, w.work);
          rotated = true;
        }
        report.qp_levels[l] = true;
        ++report.num_qp;
        if (!SolveLevelQp(w, *w.qps[l], Z_blk, m, rho, mi, report.dampings[l],
                          options.qp_regularization, &report)) {
          ++report.qp_failures;
        }
      }
      // r == 0: v is fixed by the levels above; the slack below records the violation.
    }
    if (rho > 0 && !rotated && l < last_rotation_level) {
      RotateBasis(Z_blk, w.Mt.topLeftCorner(r, m), w.hcoeffs, rho, w.work);
    }
    // Carry the level's inequality rows, shifted by their optimal slack s = Cv - clip(Cv).
    for (int i = 0; i < mi; ++i) {
      const double value = RowValue(w, i, w.x);
      const double slack = value - std::clamp(value, w.clo[i], w.chi[i]);
      const int j = w.num_carried++;
      w.g_col[j] = w.c_col[i];
      if (w.c_col[i] < 0) w.G.row(j) = w.C.row(i);
      w.glo[j] = w.clo[i] + (std::abs(slack) > tol ? slack : 0.0);
      w.ghi[j] = w.chi[i] + (std::abs(slack) > tol ? slack : 0.0);
    }
    report.ranks[l] = rho;
    off += rho;
  }
  report.remaining_dof = n - off;
  *v = w.x;
}

}  // namespace marionette::sot
