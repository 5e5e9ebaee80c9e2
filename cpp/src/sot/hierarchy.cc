#include "marionette/sot/hierarchy.h"

#include <Eigen/Cholesky>
#include <Eigen/Householder>
#include <algorithm>
#include <cmath>

#include <eiquadprog/eiquadprog-fast.hpp>

namespace marionette::sot {

namespace {}  // namespace

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
      if (t.rows < 1)
        throw SotError("Hierarchy: a task of level " + std::to_string(l) + " has no row");
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
              mi = std::max(1, h.max_inequality_rows()),
              mc = std::max(1, h.total_inequality_rows());
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
    norms_exact.resize(me);
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
    B1.resize(n, n);
    Gram.resize(n, n);
    order.resize(n);
    in_group.resize(n);
    row_count.resize(me);
    R1.resize(n, me);
    H1.resize(n, n);
    AW.resize(n, n);
    HiA.resize(n, n);
    S.resize(n, n);
    for (Eigen::VectorXd* e : {&g1, &hig, &lambda, &ut, &a_row, &dx, &x_free}) e->resize(n);
    row_old.resize(mc);
    row_live.resize(mc);
    W_rows.reserve(mc);
    W_sides.reserve(mc);
    active.resize(h.levels().size());
    for (auto& a : active) a.reserve(mc);
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
  Eigen::VectorXd hcoeffs, norms, norms_exact, c, cperm, y;
  std::vector<int> perm;
  // Sparse first level (FirstLevelStructure): Z = P, the identity with its columns ordered as
  // `order` (the s coordinates the level's sparse rows touch first); the first ρ_1 reflectors
  // then act on those s coordinates only, and B1 (s x s) accumulates them (RotateBasis).
  // in_group: per coordinate, whether it is in S (then per row of A, scratch).
  Eigen::MatrixXd B1;
  // A level solved on its Gram matrix (GramLevel): M^T M (r x r, symmetric), its Cholesky
  // factor going to H1 and -M^T c to g1 (the active-set shortcut's H and g for ρ = r).
  Eigen::MatrixXd Gram;
  bool gram = false;
  std::vector<int> order;
  std::vector<char> in_group;
  std::vector<int> row_count;
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
  // Active-set shortcut (TryActiveSet), all in the r coordinates ũ of the rotated Z_blk:
  // R1 (ρ x m) the level's triangular factor, H1 = R1 R1^T + (μ² + 1e-12) I (ρ x ρ, then its
  // Cholesky factor in place), g1 = -R1 cperm (ρ), hig = H^-1 g (r); for the k fixed rows:
  // AW (r x k) their directions, HiA = H^-1 AW (r x k), S = AW^T H^-1 AW (k x k), lambda (k);
  // ut the candidate ũ (r), a_row one carried row's direction (r), dx a step in v (n), x_free
  // the unconstrained step (n).
  Eigen::MatrixXd R1, H1, AW, HiA, S;
  Eigen::VectorXd g1, hig, lambda, ut, a_row, dx, x_free;
  // Per carried row, for the level's TryActiveSet: its value at x_old and whether the levels
  // above left it free (CarriedRow's verdict, computed once per level instead of per check).
  Eigen::VectorXd row_old;
  std::vector<char> row_live;
  // The working set: carried-row index, side (+1 upper, -1 lower).
  std::vector<int> W_rows, W_sides;
  // Per level, the carried rows active at the last tick's QP optimum (row, side): only the
  // first guess, never the result.
  std::vector<std::vector<std::pair<int, int>>> active;
};

HierarchyWorkspace::HierarchyWorkspace(const Hierarchy& hierarchy)
    : impl_(std::make_unique<Impl>(hierarchy)) {
  report_.ranks.assign(hierarchy.num_levels(), 0);
  report_.qp_levels.assign(hierarchy.num_levels(), false);
  report_.active_set_levels.assign(hierarchy.num_levels(), false);
  report_.gram_levels.assign(hierarchy.num_levels(), false);
  report_.dampings.assign(hierarchy.num_levels(), 0.0);
}
HierarchyWorkspace::~HierarchyWorkspace() = default;
HierarchyWorkspace::HierarchyWorkspace(HierarchyWorkspace&&) noexcept = default;

namespace {

using Impl = HierarchyWorkspace::Impl;

// Householder QR with column pivoting of mt (r x m): mt Π = Q R, Q = H_0 H_1 ... H_{ρ-1}.
// Stops when the largest remaining column norm is <= threshold (a row of A Z that is a
// combination of the others, or that higher levels already fixed, up to rounding). Returns ρ.
// perm holds the columns' row indices on entry (permuted along with the columns).
// The remaining column norms are downdated after each reflector, ||a_i||² -= R_ji² (Golub &
// Van Loan 2013 §5.4.2, LAPACK dlaqp2), and recomputed when cancellation leaves less than
// 1e-8 of the last exact value (the downdate's rounding is then no longer small against it);
// the chosen pivot's norm, on which the rank decision rests, is always recomputed exactly, and
// before stopping every remaining norm is, so ρ is the one of exact norms.
// Group (m1 > 0): columns [0, m1) are zero below row s; they are factored first, pivoting among
// themselves, each reflector then touching rows [j, s) only (its vector is zero below s), until
// their remaining norms are all <= threshold; *rho1 receives that count. The rank is the same
// (exact norms decide it either way); only the order of the pivots is constrained.
int PivotedQr(Eigen::Ref<Eigen::MatrixXd> mt, std::vector<int>& perm, Eigen::VectorXd& hcoeffs,
              Eigen::VectorXd& norms, Eigen::VectorXd& exact, Eigen::VectorXd& work,
              double threshold, int m1, int s, int* rho1) {
  const int r = static_cast<int>(mt.rows()), m = static_cast<int>(mt.cols());
  for (int i = 0; i < m; ++i) norms[i] = exact[i] = mt.col(i).squaredNorm();
  const int steps = std::min(r, m);
  *rho1 = 0;
  auto argmax = [&](int j, int end) {
    int p = j;
    for (int i = j + 1; i < end; ++i) {
      if (norms[i] > norms[p]) p = i;
    }
    return p;
  };
  for (int j = 0; j < steps; ++j) {
    const bool grouped = j < m1;
    const int end = grouped ? m1 : m;
    int p = argmax(j, end);
    norms[p] = exact[p] = mt.col(p).tail(r - j).squaredNorm();
    if (std::sqrt(norms[p]) <= threshold) {
      for (int i = j; i < end; ++i) norms[i] = exact[i] = mt.col(i).tail(r - j).squaredNorm();
      p = argmax(j, end);
    }
    const double pivot = std::sqrt(norms[p]);
    if (grouped && (pivot <= threshold || pivot == 0.0)) {
      // The group is exhausted: its remaining columns are dependent; continue with all.
      m1 = 0;
      --j;
      continue;
    }
    if (pivot <= threshold || pivot == 0.0) return j;
    if (p != j) {
      mt.col(j).swap(mt.col(p));
      std::swap(perm[j], perm[p]);
      std::swap(norms[j], norms[p]);
      std::swap(exact[j], exact[p]);
    }
    const int len = grouped ? s - j : r - j;  // rows the reflector touches
    if (grouped) *rho1 = j + 1;
    double tau, beta;
    mt.col(j).segment(j, len).makeHouseholderInPlace(tau, beta);
    mt(j, j) = beta;
    hcoeffs[j] = tau;
    if (j + 1 < m) {
      mt.block(j, j + 1, len, m - j - 1)
          .applyHouseholderOnTheLeft(mt.col(j).segment(j + 1, len - 1), tau, work.data());
      for (int i = j + 1; i < m; ++i) {
        norms[i] -= mt(j, i) * mt(j, i);
        if (!(norms[i] > 1e-8 * exact[i])) {
          norms[i] = exact[i] = mt.col(i).tail(r - j - 1).squaredNorm();
        }
      }
    }
  }
  return steps;
}

// Z_blk <- Z_blk H_0 ... H_{ρ-1}: its first ρ columns then span range(M^T), the others null(M).
// With a group (rho1 > 0, the first level: Z_blk = P, see FirstLevelStructure), the first ρ_1
// reflectors touch the s first coordinates only, i.e. columns [0, s) of P = [e_order[0] ...]:
// they are accumulated on the s x s identity (B1) and scattered into the rows order[0..s) —
// O(s² ρ_1) instead of O(n r ρ_1) (TALOS: the feet touch 18 of 38 coordinates).
void RotateBasis(Impl& w, Eigen::Ref<Eigen::MatrixXd> Z_blk,
                 const Eigen::Ref<const Eigen::MatrixXd>& mt, int rho, int rho1, int s) {
  const int r = static_cast<int>(Z_blk.cols());
  int j = 0;
  if (rho1 > 0) {
    auto B = w.B1.topLeftCorner(s, s);
    B.setIdentity();
    for (; j < rho1; ++j) {
      B.rightCols(s - j).applyHouseholderOnTheRight(mt.col(j).segment(j + 1, s - j - 1),
                                                    w.hcoeffs[j], w.work.data());
    }
    for (int k = 0; k < s; ++k) Z_blk.row(w.order[k]).head(s) = B.row(k);
  }
  for (; j < rho; ++j) {
    Z_blk.rightCols(r - j).applyHouseholderOnTheRight(mt.col(j).tail(r - j - 1), w.hcoeffs[j],
                                                      w.work.data());
  }
}

// The first level with equality rows (Z = I so far) when some of its rows touch few coordinates
// (a foot's Jacobian: the free flyer and one leg). S = the coordinates touched by the rows that
// leave out at least half of them; the group = the rows within S. When the group is not empty
// and S is not nearly everything, Z becomes P (columns e_order[k], S first) and the group's rows
// are put first in perm; returns the group's size m1 and writes s = |S| (0: no structure, Z and
// perm untouched). PivotedQr and RotateBasis then work on s coordinates for the group.
int FirstLevelStructure(Impl& w, int n, int m, int* s) {
  *s = 0;
  // Column-wise passes over A (column-major): nonzeros per row, then S, then rows outside S.
  auto& count = w.row_count;  // per row: nonzeros, then nonzeros outside S
  std::fill(count.begin(), count.begin() + m, 0);
  for (int c = 0; c < n; ++c) {
    for (int i = 0; i < m; ++i) count[i] += w.A(i, c) != 0.0;
  }
  int size = 0;
  for (int c = 0; c < n; ++c) {
    char touched = 0;
    for (int i = 0; i < m && !touched; ++i) touched = w.A(i, c) != 0.0 && 2 * count[i] <= n;
    w.in_group[c] = touched;
    size += touched;
  }
  if (size == 0 || size + 4 > n) return 0;  // no sparse row, or too little to gain
  std::fill(count.begin(), count.begin() + m, 0);
  for (int c = 0; c < n; ++c) {
    if (w.in_group[c]) continue;
    for (int i = 0; i < m; ++i) count[i] += w.A(i, c) != 0.0;
  }
  // perm: the group's rows (no nonzero outside S), then the others. order: S, then the rest.
  int m1 = 0;
  for (int i = 0; i < m; ++i) m1 += count[i] == 0;
  if (m1 == 0) return 0;
  for (int i = 0, k1 = 0, k2 = m1; i < m; ++i) (count[i] == 0 ? w.perm[k1++] : w.perm[k2++]) = i;
  for (int c = 0, k = 0, k2 = size; c < n; ++c) w.order[w.in_group[c] ? k++ : k2++] = c;
  w.Z.setZero();
  for (int k = 0; k < n; ++k) w.Z(w.order[k], k) = 1.0;
  *s = size;
  return m1;
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

// A level whose rows outnumber the remaining DoF (m >= r; TALOS's posture: 32 rows on 11 DoF)
// and use them all: M = A Z_blk (m x r, mt = M^T) then has full column rank r, its
// least-squares step needs no rank-revealing factorization, and nothing remains to rotate:
//   u = (M^T M)^-1 M^T c,  v += Z_blk u,  ρ = r,
// and a QP on the level (the active-set shortcut, eiquadprog) has the objective
// ½ u^T M^T M u - c^T M u in the unrotated coordinates u (= ũ, ũ_1 being all of them). Taken
// only when the Cholesky factor L of M^T M (|L_ii| = |R_ii| of the unpivoted QR of M, each
// >= σ_min) shows a well-conditioned M: min |L_ii| >= the damping threshold (so the level
// needs no damping; with damping off, >= 1e-4 x the row scale), and max/min |L_ii| <= 100 (the
// normal equations' error ~ε κ² then stays ~1e-12). Otherwise false, and the pivoted QR path
// (rank, damping) decides as before. Replaces a QR of the r x m mt, a QR of the least squares
// and, under a QP, the basis rotation by one r x r Gram product and its Cholesky factor.
bool GramLevel(Impl& w, const Eigen::Ref<const Eigen::MatrixXd>& mt, int m, double row_scale,
               const HierarchyOptions& options) {
  const int r = static_cast<int>(mt.rows());
  auto G = w.Gram.topLeftCorner(r, r);
  G.setZero();
  G.selfadjointView<Eigen::Lower>().rankUpdate(mt);
  auto H = w.H1.topLeftCorner(r, r);
  H.triangularView<Eigen::Lower>() = G.triangularView<Eigen::Lower>();
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(H);  // in place: no allocation
  if (llt.info() != Eigen::Success) return false;
  const double smallest = H.diagonal().cwiseAbs().minCoeff(),
               largest = H.diagonal().cwiseAbs().maxCoeff();
  const double floor =
      options.damping > 0.0 ? options.damping_threshold : 1e-4 * std::sqrt(row_scale);
  if (!(smallest >= floor && largest <= 100.0 * smallest)) return false;
  for (int i = 0; i < r; ++i) {
    for (int j = i + 1; j < r; ++j) G(i, j) = G(j, i);  // the QP fallback reads all of it
  }
  w.g1.head(r).noalias() = -mt * w.cperm.head(m);  // mt's column i is row perm[i] of A
  w.u.head(r) = -w.g1.head(r);
  llt.solveInPlace(w.u.head(r));
  return true;
}

// Least squares min ||R1^T y - cperm||² + μ²||y||² with R1 = upper part of mt's first ρ rows
// (ρ x m). Plain triangular solve when full row rank and undamped. Otherwise, when the system
// is well conditioned, its normal equations (R1 R1^T + μ² I) y = R1 cperm by Cholesky (half the
// cost of the QR of [R1^T; μ I] for TALOS's posture level, m = 32 rows on ρ = 11 DoF): their
// relative error is ~ε κ², κ² = (σ_max² + μ²) / (σ_min² + μ²), estimated from the pivoted
// QR's diagonal (|R_00| ~ σ_max, |R_ρ-1,ρ-1| ~ σ_min); accepted up to 1e4 (error ~1e-12,
// allowing for the estimate's looseness), else the QR below.
void SolveLeastSquares(Impl& w, int m, int rho, double mu) {
  auto R1 = w.Mt.topLeftCorner(rho, m);
  if (rho == m && mu == 0.0) {
    w.y.head(rho) = w.cperm.head(rho);
    R1.leftCols(rho).triangularView<Eigen::Upper>().transpose().solveInPlace(w.y.head(rho));
    return;
  }
  const double largest = w.Mt(0, 0) * w.Mt(0, 0),
               smallest = w.Mt(rho - 1, rho - 1) * w.Mt(rho - 1, rho - 1);
  if (largest + mu * mu <= 1e4 * (smallest + mu * mu)) {
    auto U = w.R1.topLeftCorner(rho, m);  // scratch (TryActiveSet rebuilds its own)
    U = R1.triangularView<Eigen::Upper>();
    auto H = w.H1.topLeftCorner(rho, rho);
    H.setZero();
    H.selfadjointView<Eigen::Lower>().rankUpdate(U);
    H.diagonal().array() += mu * mu;
    Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(H);  // in place: no allocation
    if (llt.info() == Eigen::Success) {
      w.y.head(rho).noalias() = U * w.cperm.head(m);
      llt.solveInPlace(w.y.head(rho));
      return;
    }
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
    w.d.segment(j, mb - j).applyHouseholderOnTheLeft(B.col(j).tail(mb - j - 1), tau, w.work.data());
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
bool SolveLevelQp(Impl& w, Impl::LevelQp& q, const Eigen::Ref<const Eigen::MatrixXd>& Z_blk, int m,
                  int rho, int mi, double mu, double regularization, HierarchyReport* report) {
  const int r = static_cast<int>(Z_blk.cols()), n = static_cast<int>(Z_blk.rows());
  const int slack0 = n;  // slack variables follow the (padded) ũ
  q.H.setZero();
  q.g.setZero();
  // The level's objective directions ũ_1 (first ρ) are left exact: a regularization there
  // would bias the level's own optimum (feet drifting whenever bounds bind below them).
  q.H.diagonal().head(n).setConstant(std::max(regularization, 1e-12));
  q.H.diagonal().head(rho).setConstant(1e-12);
  q.H.diagonal().tail(q.H.rows() - n).setOnes();  // ½||s||² (and unused slacks)
  if (w.gram) {
    // ρ = r, unrotated: ½||M u - c||² = ½ u^T M^T M u - c^T M u + const.
    q.H.topLeftCorner(r, r) += w.Gram.topLeftCorner(r, r);
    q.g.head(r) = w.g1.head(r);
  } else if (rho > 0) {
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

// Direction of carried row i in the ũ coordinates (a = Z_blk^T G_i^T, r) and its value at x_old.
// Returns false for a row the levels above already fixed (|a|² < 1e-24): the QP skips it too.
bool CarriedRow(Impl& w, const Eigen::Ref<const Eigen::MatrixXd>& Z_blk, int i, double* value) {
  const int r = static_cast<int>(Z_blk.cols());
  if (w.g_col[i] >= 0) {
    w.a_row.head(r) = Z_blk.row(w.g_col[i]).transpose();
    *value = w.x_old[w.g_col[i]];
  } else {
    w.a_row.head(r).noalias() = Z_blk.transpose() * w.G.row(i).transpose();
    *value = w.G.row(i).dot(w.x_old);
  }
  return w.a_row.head(r).squaredNorm() >= 1e-24;
}

// ũ ← H^-1 ũ for H = blockdiag(H1 (Cholesky-factored in place), ε I_{r-ρ}).
void ApplyHInverse(const Impl& w, int rho, double eps, Eigen::Ref<Eigen::VectorXd> u) {
  if (rho > 0) {
    const auto L = w.H1.topLeftCorner(rho, rho);
    L.triangularView<Eigen::Lower>().solveInPlace(u.head(rho));
    L.triangularView<Eigen::Lower>().transpose().solveInPlace(u.head(rho));
  }
  u.tail(u.size() - rho) /= eps;
}

// Active-set shortcut for a QP level without inequality rows of its own (mi = 0). The level's
// QP (SolveLevelQp, the same objective and the same widened bounds) is
//   min_ũ ½ ũ^T H ũ + g^T ũ   s.t.  lo'_i <= value_i + a_i^T ũ <= hi'_i  (carried rows i)
// with H = blockdiag(R1 R1^T + (μ² + 1e-12) I_ρ, ε I_{r-ρ}), ε = max(regularization, 1e-12),
// g = [-R1 cperm; 0]: strictly convex, so a point satisfying its KKT conditions is its unique
// optimum (Nocedal & Wright 2006, Thm 16.4), the one eiquadprog returns. For a working set W of
// rows fixed at a bound (A_W ũ = β_W) the equality QP is solved by its Schur complement:
//   S λ = β_W + A_W H^-1 g,  S = A_W H^-1 A_W^T,  ũ = H^-1 (A_W^T λ - g)
// (stationarity H ũ + g = A_W^T λ; H^-1 is cheap, H being block diagonal). The point is the
// QP's optimum when every carried row is within its bounds and every λ_i has the sign of a
// binding bound (λ_i <= 0 on an upper bound, >= 0 on a lower one).
//  1. Warm guess: W = the rows active at the last tick's optimum (at 1 kHz the active set
//     rarely changes); accepted only if the KKT conditions verify.
//  2. Else the primal active-set method (Nocedal & Wright §16.5) from ũ = 0, which is feasible
//     (the bounds are widened to include x_old): step towards the equality-QP solution up to
//     the first blocking row, which joins W (its direction is independent of W's, so S stays
//     positive definite), or, at a full step, drop the row with the worst multiplier; stop when
//     none is wrong.
// Returns false (→ eiquadprog) on a rank-deficient W, on rounding leaving the final point off
// the KKT conditions by more than tol, or after too many iterations (degenerate cycling).
// On success writes w.x and records W as the level's next first guess.
bool TryActiveSet(Impl& w, int level, const Eigen::Ref<const Eigen::MatrixXd>& Z_blk, int m,
                  int rho, double mu, double regularization, double tol) {
  const int r = static_cast<int>(Z_blk.cols());
  if (r == 0) return false;
  const double eps = std::max(regularization, 1e-12);
  if (rho > 0 && !w.gram) {  // (a Gram level has set H1 and g1, ρ = r)
    auto R1 = w.R1.topLeftCorner(rho, m);
    R1 = w.Mt.topLeftCorner(rho, m);
    R1.triangularView<Eigen::StrictlyLower>().setZero();
    auto H1 = w.H1.topLeftCorner(rho, rho);
    H1.noalias() = R1 * R1.transpose();
    H1.diagonal().array() += mu * mu + 1e-12;
    Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(H1);  // in place: no allocation
    if (llt.info() != Eigen::Success) return false;
    w.g1.head(rho).noalias() = -R1 * w.cperm.head(m);
  }
  w.hig.head(r).setZero();
  w.hig.head(rho) = w.g1.head(rho);
  ApplyHInverse(w, rho, eps, w.hig.head(r));
  // The QP's bounds: widened to include the current value (rounding of the levels above may
  // leave it ~1e-15 outside).
  auto bound = [&](int i, int side, double value_old) {
    return side > 0 ? std::max(w.ghi[i], value_old) : std::min(w.glo[i], value_old);
  };
  auto row_value = [&](int i, const Eigen::VectorXd& x) {
    return w.g_col[i] >= 0 ? x[w.g_col[i]] : w.G.row(i).dot(x);
  };
  // Solves the equality QP of W into w.ut (r) and w.lambda (k); false if S is not positive
  // definite.
  auto solve_working_set = [&]() {
    const int k = static_cast<int>(w.W_rows.size());
    w.ut.head(r) = -w.hig.head(r);
    if (k == 0) return true;
    if (k > r) return false;
    auto AW = w.AW.topLeftCorner(r, k);
    auto HiA = w.HiA.topLeftCorner(r, k);
    auto lambda = w.lambda.head(k);
    for (int i = 0; i < k; ++i) {
      double value_old;
      CarriedRow(w, Z_blk, w.W_rows[i], &value_old);
      AW.col(i) = w.a_row.head(r);
      HiA.col(i) = w.a_row.head(r);
      ApplyHInverse(w, rho, eps, HiA.col(i));
      lambda[i] = bound(w.W_rows[i], w.W_sides[i], value_old) - value_old;  // β_i
    }
    lambda.noalias() += AW.transpose() * w.hig.head(r);
    auto S = w.S.topLeftCorner(k, k);
    S.noalias() = AW.transpose() * HiA;
    Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(S);
    if (llt.info() != Eigen::Success) return false;
    const auto L = w.S.topLeftCorner(k, k);
    L.triangularView<Eigen::Lower>().solveInPlace(lambda);
    L.triangularView<Eigen::Lower>().transpose().solveInPlace(lambda);
    w.ut.head(r).noalias() += HiA * lambda;
    return true;
  };
  // KKT check of w.ut (with w.lambda): returns the index in W of the worst multiplier (-1 if
  // none), or -2 when a row is off its bounds by more than tol.
  auto verify = [&]() {
    w.x = w.x_old;
    w.x.noalias() += Z_blk * w.ut.head(r);
    const int k = static_cast<int>(w.W_rows.size());
    for (int i = 0; i < w.num_carried; ++i) {
      const double value_old = row_value(i, w.x_old), value = row_value(i, w.x);
      const auto it = std::find(w.W_rows.begin(), w.W_rows.end(), i);
      if (it != w.W_rows.end()) {  // W's rows are free (checked when they joined)
        const int side = w.W_sides[it - w.W_rows.begin()];
        if (std::abs(value - bound(i, side, value_old)) > tol) return -2;
      } else if (!Inside(value, bound(i, -1, value_old), bound(i, 1, value_old), tol)) {
        // Off its bounds: a failure unless the levels above fixed the row (the QP skips it
        // too); that costlier check only here, where it decides.
        double unused;
        if (CarriedRow(w, Z_blk, i, &unused)) return -2;
      }
    }
    int wrong = -1;
    for (int i = 0; i < k; ++i) {
      const double pull = w.W_sides[i] * w.lambda[i];
      if (pull > 0.0 && (wrong < 0 || pull > w.W_sides[wrong] * w.lambda[wrong])) wrong = i;
    }
    return wrong;
  };
  auto accept = [&]() {
    w.active[level].clear();
    for (size_t i = 0; i < w.W_rows.size(); ++i)
      w.active[level].emplace_back(w.W_rows[i], w.W_sides[i]);
    return true;
  };
  // 1. The warm guess.
  w.W_rows.clear();
  w.W_sides.clear();
  for (const auto& [row, side] : w.active[level]) {
    double value_old;
    if (row < w.num_carried && CarriedRow(w, Z_blk, row, &value_old) &&
        !std::isinf(side > 0 ? w.ghi[row] : w.glo[row])) {
      w.W_rows.push_back(row);
      w.W_sides.push_back(side);
    }
  }
  if (!w.W_rows.empty() && solve_working_set() && verify() == -1) return accept();
  // 2. The primal active-set method from ũ = 0.
  w.W_rows.clear();
  w.W_sides.clear();
  auto current = w.u.head(r);  // the feasible iterate ũ (r); w.u is free after the level's step
  current.setZero();
  for (int i = 0; i < w.num_carried; ++i) {
    double value_old;
    w.row_live[i] = CarriedRow(w, Z_blk, i, &value_old);
    w.row_old[i] = value_old;
  }
  const int max_iterations = 2 * r + 10;
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    if (!solve_working_set()) return false;
    // Step p = ũ_W - ũ; in v: dx = Z p, from x_cur = x_old + Z ũ.
    w.ut.head(r) -= current;
    w.dx.noalias() = Z_blk * w.ut.head(r);
    w.x = w.x_old;
    w.x.noalias() += Z_blk * current;  // x_cur
    double alpha = 1.0;
    int blocking = -1, blocking_side = 0;
    for (int i = 0; i < w.num_carried; ++i) {
      if (std::find(w.W_rows.begin(), w.W_rows.end(), i) != w.W_rows.end()) continue;
      if (!w.row_live[i]) continue;  // fixed above: never blocks
      const double value_old = w.row_old[i];
      const double slope = row_value(i, w.dx), value = row_value(i, w.x);
      double step = 1.0;
      int side = 0;
      if (slope > 0.0 && !std::isinf(w.ghi[i])) {
        step = (bound(i, 1, value_old) - value) / slope;
        side = 1;
      } else if (slope < 0.0 && !std::isinf(w.glo[i])) {
        step = (bound(i, -1, value_old) - value) / slope;
        side = -1;
      }
      if (side != 0 && step < alpha) {
        alpha = std::max(step, 0.0);
        blocking = i;
        blocking_side = side;
      }
    }
    if (blocking >= 0) {
      current.noalias() += alpha * w.ut.head(r);
      w.W_rows.push_back(blocking);
      w.W_sides.push_back(blocking_side);
      continue;
    }
    current += w.ut.head(r);  // full step: ũ = ũ_W
    w.ut.head(r) = current;
    const int wrong = verify();
    if (wrong == -2) return false;
    if (wrong == -1) return accept();
    w.W_rows.erase(w.W_rows.begin() + wrong);
    w.W_sides.erase(w.W_sides.begin() + wrong);
  }
  return false;
}

// After an eiquadprog solve, the carried rows at their bounds: the next tick's first guess.
void RecordActiveBounds(Impl& w, int level, double tol) {
  w.active[level].clear();
  for (int i = 0; i < w.num_carried; ++i) {
    const double value = w.g_col[i] >= 0 ? w.x[w.g_col[i]] : w.G.row(i).dot(w.x);
    if (std::abs(value - w.ghi[i]) <= tol) {
      w.active[level].emplace_back(i, 1);
    } else if (std::abs(value - w.glo[i]) <= tol) {
      w.active[level].emplace_back(i, -1);
    }
  }
}

}  // namespace

void SolveHierarchy(const Hierarchy& hierarchy, const std::vector<const TaskTerms*>& tasks,
                    HierarchyWorkspace* workspace, Eigen::VectorXd* v,
                    const Eigen::VectorXd* target_offsets) {
  const int n = hierarchy.nv();
  if (static_cast<int>(tasks.size()) != hierarchy.num_tasks()) {
    throw SotError("SolveHierarchy: " + std::to_string(tasks.size()) +
                   " tasks given, the hierarchy has " + std::to_string(hierarchy.num_tasks()));
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
  report.num_active_set = 0;
  report.qp_failures = 0;
  w.Z.setIdentity();
  w.x.setZero();
  w.num_carried = 0;
  int off = 0;  // Z's first free column
  int k = 0;    // task index
  int row = 0;  // first row of task k among all tasks' rows
  const int num_levels = hierarchy.num_levels();
  // A level's basis rotation (Z's trailing columns onto null(A Z)) is deferred until a level
  // below reads Z: the next level with equality rows (its M = A Z), or a QP (its variables are
  // the coordinates of Z). A stack whose last levels need neither (posture last, or inequality
  // levels whose unconstrained step keeps them) never pays for it. Until then the level's
  // reflectors stay in Mt: only an equality level overwrites it, and it applies them first.
  struct PendingRotation {
    int off = 0, r = 0, m = 0, rho = 0, rho1 = 0, s_group = 0;
  } pending;
  auto rotate_pending = [&]() {
    if (pending.rho == 0) return;
    RotateBasis(w, w.Z.middleCols(pending.off, pending.r), w.Mt.topLeftCorner(pending.r, pending.m),
                pending.rho, pending.rho1, pending.s_group);
    pending.rho = 0;
  };
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
    report.active_set_levels[l] = false;
    report.gram_levels[l] = false;
    report.dampings[l] = 0.0;
    w.x_old = w.x;
    int rho = 0, rho1 = 0, m1 = 0, s_group = 0;
    w.gram = false;
    bool rotated = false;
    auto Z_blk = w.Z.middleCols(off, r);
    if (m > 0 && r > 0) {
      rotate_pending();
      auto mt = w.Mt.topLeftCorner(r, m);
      if (dense) {
        // Unit rows are filled as rows of the identity so one product serves all rows.
        for (int i = 0; i < m; ++i) {
          if (w.a_col[i] >= 0) {
            w.A.row(i).setZero();
            w.A(i, w.a_col[i]) = 1.0;
          }
        }
        for (int i = 0; i < m; ++i) w.perm[i] = i;
        if (off == 0) {
          // Z = I before the first equality level; P if the level has sparse rows.
          m1 = FirstLevelStructure(w, n, m, &s_group);
          if (m1 > 0) {
            for (int k = 0; k < r; ++k) {
              for (int i = 0; i < m; ++i) mt(k, i) = w.A(w.perm[i], w.order[k]);
            }
          } else {
            mt = w.A.topRows(m).transpose();
          }
        } else {
          mt.noalias() = Z_blk.transpose() * w.A.topRows(m).transpose();
        }
        w.c.head(m).noalias() = w.b.head(m) - w.A.topRows(m) * w.x;
      } else {
        for (int i = 0; i < m; ++i) {
          w.perm[i] = i;
          mt.col(i) = Z_blk.row(w.a_col[i]).transpose();
          w.c[i] = w.b[i] - w.x[w.a_col[i]];
        }
      }
      for (int i = 0; i < m; ++i) w.cperm[i] = w.c[w.perm[i]];
      w.gram = m >= r && GramLevel(w, mt, m, row_scale, options);
      if (w.gram) {
        rho = r;
        report.gram_levels[l] = true;
        w.x.noalias() += Z_blk * w.u.head(r);
      } else {
        rho = PivotedQr(mt, w.perm, w.hcoeffs, w.norms, w.norms_exact, w.work,
                        options.rank_tolerance * std::sqrt(row_scale), m1, s_group, &rho1);
        for (int i = 0; i < m; ++i) w.cperm[i] = w.c[w.perm[i]];
      }
      if (rho > 0 && !w.gram) {
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
    const bool inside = CarriedFeasible(w, w.x, tol) && LevelFeasible(w, mi, w.x, tol);
    if (inside) w.active[l].clear();
    if (w.num_carried + mi > 0 && !inside) {
      if (r > 0) {
        rotate_pending();          // (a level above's; this level's own follows)
        if (rho > 0 && !w.gram) {  // a Gram level's QP works in the unrotated u
          RotateBasis(w, Z_blk, w.Mt.topLeftCorner(r, m), rho, rho1, s_group);
          rotated = true;
        }
        report.qp_levels[l] = true;
        ++report.num_qp;
        w.x_free = w.x;  // the unconstrained step, kept if the QP fails too
        if (options.active_set_shortcut && mi == 0 &&
            TryActiveSet(w, l, Z_blk, m, rho, report.dampings[l], options.qp_regularization, tol)) {
          report.active_set_levels[l] = true;
          ++report.num_active_set;
        } else if (!SolveLevelQp(w, *w.qps[l], Z_blk, m, rho, mi, report.dampings[l],
                                 options.qp_regularization, &report)) {
          w.x = w.x_free;
          ++report.qp_failures;
        } else {
          RecordActiveBounds(w, l, 1e-9);
        }
      }
      // r == 0: v is fixed by the levels above; the slack below records the violation.
    }
    if (rho > 0 && !rotated && !w.gram) {  // (Gram: ρ = r, no null space)
      pending = {off, r, m, rho, rho1, s_group};
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
    if (m1 > 0 && rho == 0) w.Z.setIdentity();  // nothing was rotated: back to Z = I
    report.ranks[l] = rho;
    off += rho;
  }
  report.remaining_dof = n - off;
  *v = w.x;
}

}  // namespace marionette::sot
