#include "marionette/sot/hierarchy.h"

#include <Eigen/Cholesky>
#include <Eigen/Householder>
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "third_party/eiquadprog/eiquadprog-fast.hpp"

namespace marionette::sot {

namespace {
// row_live of a QP row whose norm in the QP's coordinates is not known yet (see FormQpDirection).
constexpr char kLiveUnknown = 2;
}  // namespace

Hierarchy::Hierarchy(int nv, std::vector<std::vector<TaskShape>> levels, HierarchyOptions options)
    : nv_(nv), levels_(std::move(levels)), options_(options) {
  if (nv_ < 1) throw SotError("Hierarchy: nv must be >= 1, got " + std::to_string(nv_));
  if (!(options_.rank_tolerance > 0.0) || options_.damping < 0.0 ||
      !(options_.damping_threshold > 0.0) || !(options_.constraint_tolerance >= 0.0) ||
      !(options_.qp_regularization >= 0.0) || options_.qp_max_iterations < 1) {
    throw SotError(
        "Hierarchy: invalid options (tolerances > 0, damping and qp_regularization >= 0, "
        "iterations >= 1)");
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
    Q_null.resize(n, n);
    Z_null.resize(n, n);
    Gram.resize(n, n);
    Ycomp.resize(n, n);
    covered.resize(n);
    order.resize(n);
    structure_perm.resize(me);
    in_group.resize(n);
    row_count.resize(me);
    row_sparse.resize(me);
    R1.resize(n, me);
    H1.resize(n, n);
    Hfull.resize(n, n);
    K.resize(n, n);
    AW.resize(n, n);
    HiA.resize(n, n);
    S.resize(n, n);
    for (Eigen::VectorXd* e : {&g1, &hig, &lambda, &ut, &dx, &beta, &residual, &qr_tau, &grad})
      e->resize(n);
    qr_perm.resize(n);
    chol_perm.resize(n);
    chol_tmp.resize(n);
    b22.resize(n);
    M22.resize(n, n);
    D.resize(n, mc);
    Dq.resize(n, mc);
    dq_formed.assign(mc, 0);
    y_point.resize(n);
    y_step.resize(n);
    step.resize(n);
    dv.resize(n);
    for (Eigen::VectorXd* e : {&row_val, &row_lo, &row_hi, &live_threshold}) e->resize(mc);
    row_live.resize(mc);
    in_W.assign(mc, 0);
    implied.assign(mc, 0);
    s_eqp.resize(mi);
    s_cur.resize(mi);
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
  // in_group: per coordinate, whether it is in S.
  Eigen::MatrixXd B1;
  // RotateBasis when only the null space is wanted: the reflectors' product on its trailing
  // columns (Q_null), and Z_blk times it (Z_null), before it is copied back into Z.
  Eigen::MatrixXd Q_null, Z_null;
  // A level solved on its Gram matrix (GramLevel): M^T M (r x r, symmetric), its Cholesky
  // factor going to H1 and -M^T c to g1 (the active-set shortcut's H and g for ρ = r).
  Eigen::MatrixXd Gram;
  bool gram = false;
  // GramFromComplement: Z_blk's rows at the coordinates the level leaves out (Ycomp), and which
  // coordinates it covers.
  Eigen::MatrixXd Ycomp;
  std::vector<char> covered;
  std::vector<int> order;
  // The last structure FirstLevelStructure found (its m, m1, s and initial perm; order is kept in
  // `order`), reused while it still holds: m1 = 0 when there is none to reuse.
  int structure_m = 0, structure_m1 = 0, structure_s = 0;
  std::vector<int> structure_perm;
  std::vector<char> in_group;
  std::vector<std::int64_t> row_count, row_sparse;
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
    Eigen::MatrixXd H, CI, CE;
    Eigen::VectorXd g, ci0, ce0, z, row;
    third_party::eiquadprog::solvers::EiquadprogFast solver;
  };
  std::vector<std::unique_ptr<LevelQp>> qps;
  // The level QP (see SolveQp), in the r coordinates ũ of its basis (QpShape). Its objective:
  // with R1 (ρ x m) the level's triangular factor (the upper part of Mt's first ρ rows),
  // H1 = R1 R1^T + μ² I (ρ x ρ, then its Cholesky factor in place), g1 = -R1 cperm (ρ), Hfull
  // the whole H (r x r, unfactored); R1 itself is SolveLeastSquares' scratch. Its rows (carried,
  // then the level's own; t < nc + mi): D.col(t) their directions in the formed block F's
  // coordinates, Dq.col(t) in ũ (formed when first needed: dq_formed), row_val their values at
  // x_old, row_lo / row_hi their bounds, row_live whether the levels above left them free.
  // Scratch: y_point (a point of ũ in F's coordinates, ToBasis), y_step (FormQpDirection's and
  // GramFromComplement's), step (the primal method's step in F's coordinates), dv (Verify's F y).
  Eigen::MatrixXd R1, H1, Hfull, D, Dq;
  Eigen::VectorXd g1, row_val, row_lo, row_hi, y_point, y_step, step, dv;
  std::vector<char> dq_formed;
  double qp_scale = 0.0;       // the largest curvature or squared row norm of the QP
  std::vector<char> row_live;  // 0 dead, 1 live, kLiveUnknown (read as live) until formed
  Eigen::VectorXd live_threshold;
  // The primal method's rows found dependent on W's when they joined it (see PrimalActiveSet).
  std::vector<char> implied;
  // The working set: rows (t), sides (+1 upper, -1 lower), in_W per row. Its equality QP: K
  // (r x r, H plus the own rows of W, factored), hig = K^-1 g_W (r), for its kc carried rows
  // AW (r x kc) their directions, HiA = K^-1 AW, S = AW^T HiA (kc x kc), beta their targets,
  // lambda their multipliers, residual (refinement); ut its point ũ (r), s_eqp its slacks
  // (mi). The primal method's iterate: u (ũ, r) and s_cur (mi); dx its step (r).
  std::vector<int> W_rows, W_sides;
  std::vector<char> in_W;
  Eigen::MatrixXd K, AW, HiA, S;
  Eigen::VectorXd hig, lambda, beta, residual, ut, dx, s_eqp, s_cur, grad;
  // The null-space method's QR of W's carried rows (NullSpaceEqp): reflector coefficients, and
  // the pivot order of the rows.
  Eigen::VectorXd qr_tau, chol_tmp, b22;
  Eigen::MatrixXd M22;  // a copy of the null-space method's reduced Hessian
  std::vector<int> qr_perm, chol_perm;
  // Per level, the working set of the last tick's QP (row, side): only the first guess, never
  // the result.
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

// x <- H x, H = I - tau [1; v] [1; v]^T, x of 1 + n contiguous entries. (One running sum: four
// independent ones, tried, changed the rounding enough to leave one QP of the cascade reference
// test uncertified: at a degenerate vertex the primal method cycled on a multiplier below 1e-8.)
inline void Reflect(double* x, const double* v, Eigen::Index n, double tau) {
  double dot = x[0];
  for (Eigen::Index i = 0; i < n; ++i) dot += v[i] * x[1 + i];
  const double s = tau * dot;
  x[0] -= s;
  for (Eigen::Index i = 0; i < n; ++i) x[1 + i] -= s * v[i];
}

// Householder reflections H = I - tau [1; v] [1; v]^T on column-major blocks, column by column
// as raw dot and axpy loops. Eigen's applyHouseholderOnTheLeft/Right compute the same through
// its gemv and rank-1 kernels, whose per-call dispatch outweighs the flops on blocks of tens of
// rows: on a 38-DoF humanoid's reference stack (bench/sot) those calls were ~40 % of a solve
// (and Eigen's dot and axpy on segments of ~20 entries cost more than their flops too).
// block <- H block (block has 1 + v.size() rows; both have contiguous columns).
template <typename Block, typename Essential>
void ReflectLeft(Block&& block, const Essential& v, double tau) {
  if (tau == 0.0) return;
  eigen_assert(block.innerStride() == 1 && v.innerStride() == 1);
  const Eigen::Index n = v.size();
  for (Eigen::Index c = 0; c < block.cols(); ++c) {
    Reflect(&block.coeffRef(0, c), v.data(), n, tau);
  }
}

// block <- block H (block has 1 + v.size() columns); acc: scratch of block.rows().
template <typename Block, typename Essential>
void ReflectRight(Block&& block, const Essential& v, double tau, Eigen::VectorXd& acc) {
  if (tau == 0.0) return;
  const Eigen::Index n = v.size();
  auto a = acc.head(block.rows());
  a = block.col(0);
  for (Eigen::Index k = 0; k < n; ++k) a += v[k] * block.col(k + 1);
  a *= tau;
  block.col(0) -= a;
  for (Eigen::Index k = 0; k < n; ++k) block.col(k + 1) -= v[k] * a;
}

// X <- I (Eigen's setIdentity tests i == j coefficient by coefficient: 0.9 µs on a 38 x 38 Z,
// against a fill and a diagonal).
template <typename Matrix>
void SetIdentity(Matrix&& X) {
  X.setZero();
  X.diagonal().setOnes();
}

// y <- Q y, or Q^T y (transpose), for Q = H_0 ... H_{k-1} the first k reflectors of a PivotedQr of
// the r x m w.Mt (r = y.size()); the first rho1 of them (a group) touch its rows [j, s) only.
void ApplyReflectors(const Impl& w, int k, int rho1, int s, Eigen::Ref<Eigen::VectorXd> y,
                     bool transpose) {
  const int r = static_cast<int>(y.size());
  const Eigen::Index ld = w.Mt.outerStride();
  double* x = y.data();
  for (int i = 0; i < k; ++i) {
    const int j = transpose ? i : k - 1 - i;
    const double tau = w.hcoeffs[j];
    if (tau == 0.0) continue;
    const int end = j < rho1 ? s : r;  // rows [j, end) the reflector touches
    Reflect(x + j, w.Mt.data() + j * ld + j + 1, end - j - 1, tau);
  }
}

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
      ReflectLeft(mt.block(j, j + 1, len, m - j - 1), mt.col(j).segment(j + 1, len - 1), tau);
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

// Rows [0, S) of X <- X H_j0 ... H_{j1-1}, X column-major with leading dimension ld and `cols`
// columns, H_j = I - tau_j w w^T acting on columns [j, cols): w = [1; mt(j+1 .. cols-1, j)].
// The S rows (a strip) stay in L1 through all the reflectors and each reflector's accumulator
// stays in registers: per element and reflector two loads and one store, where ReflectRight,
// column by column over all rows, loads and stores its accumulator too (on the humanoid's
// reference stack, 38 x 23 by 12 reflectors: ~15 % faster).
template <int S>
void ReflectStripRight(double* x, Eigen::Index ld, Eigen::Index cols, const double* mt,
                       Eigen::Index ldm, const double* tau, int j0, int j1) {
  for (int j = j0; j < j1; ++j) {
    const double t = tau[j];
    if (t == 0.0) continue;
    const double* v = mt + j * ldm + j + 1;  // v[k - j - 1] multiplies column k
    double* xj = x + j * ld;
    double acc[S];
    for (int s = 0; s < S; ++s) acc[s] = xj[s];
    for (Eigen::Index k = j + 1; k < cols; ++k) {
      const double vk = v[k - j - 1];
      const double* xk = x + k * ld;
      for (int s = 0; s < S; ++s) acc[s] += vk * xk[s];
    }
    for (int s = 0; s < S; ++s) {
      acc[s] *= t;
      xj[s] -= acc[s];
    }
    for (Eigen::Index k = j + 1; k < cols; ++k) {
      const double vk = v[k - j - 1];
      double* xk = x + k * ld;
      for (int s = 0; s < S; ++s) xk[s] -= vk * acc[s];
    }
  }
}

// X <- X H_j0 ... H_{j1-1} (see ReflectStripRight), strip by strip of rows.
void ReflectSequenceRight(Eigen::Ref<Eigen::MatrixXd> X,
                          const Eigen::Ref<const Eigen::MatrixXd>& mt, const Eigen::VectorXd& tau,
                          int j0, int j1) {
  const Eigen::Index rows = X.rows(), cols = X.cols(), ld = X.outerStride(), ldm = mt.outerStride();
  double* x = X.data();
  Eigen::Index i = 0;
  for (; i + 8 <= rows; i += 8)
    ReflectStripRight<8>(x + i, ld, cols, mt.data(), ldm, tau.data(), j0, j1);
  for (; i + 4 <= rows; i += 4)
    ReflectStripRight<4>(x + i, ld, cols, mt.data(), ldm, tau.data(), j0, j1);
  for (; i + 2 <= rows; i += 2)
    ReflectStripRight<2>(x + i, ld, cols, mt.data(), ldm, tau.data(), j0, j1);
  for (; i < rows; ++i) ReflectStripRight<1>(x + i, ld, cols, mt.data(), ldm, tau.data(), j0, j1);
}

// The columns [ρ, r) of Z_blk H_0 ... H_{ρ-1}, i.e. of Z_blk Q, into Z_blk's: they span null(M)
// within range(Z_blk), the freedom the levels below have (they read nothing else; columns
// [0, ρ) are left stale). The product of the reflectors is formed on those columns alone, from
// the last reflector to the first (LAPACK dorg2r's order: H_j acts on rows [j, r) of columns
// that are still e_k there), i.e. Q [0; I] instead of Q.
// With a group (rho1 > 0, the first level: Z_blk = P, see FirstLevelStructure), the first ρ_1
// reflectors touch the s first coordinates only, i.e. columns [0, s) of P = [e_order[0] ...]:
// they are accumulated on s - ρ_1 columns of the s x s identity (B1) and scattered into the
// rows order[0..s) — O(s² ρ_1) instead of O(n r ρ_1) (a 38-DoF humanoid: its feet touch 18
// coordinates). For the other reflectors, when they are at least as many as the columns left
// (ρ - ρ_1 >= r - ρ: a hand level after the feet), Q [0; I] costs ~4 (r-ρ) ρ r flops and
// Z_blk Q [0; I] one matrix product (2 n r (r-ρ) flops, at the matrix kernel's speed) instead
// of ~4 n ρ r in reflections; otherwise they are applied to Z_blk as reflections.
void RotateBasis(Impl& w, Eigen::Ref<Eigen::MatrixXd> Z_blk,
                 const Eigen::Ref<const Eigen::MatrixXd>& mt, int rho, int rho1, int s) {
  const int r = static_cast<int>(Z_blk.cols()), n = static_cast<int>(Z_blk.rows());
  if (rho1 > 0) {
    auto B = w.B1.topLeftCorner(s, s - rho1);  // Q_group [0; I_{s-ρ1}]
    B.setZero();
    SetIdentity(B.bottomRows(s - rho1));
    for (int j = rho1 - 1; j >= 0; --j) {
      ReflectLeft(B.bottomRows(s - j), mt.col(j).segment(j + 1, s - j - 1), w.hcoeffs[j]);
    }
    for (int k = 0; k < s; ++k) Z_blk.row(w.order[k]).segment(rho1, s - rho1) = B.row(k);
  }
  if (rho1 == rho) return;
  if (rho - rho1 >= r - rho) {
    const int width = r - rho1;  // the reflectors act on Z_blk's columns [ρ1, r)
    auto Q = w.Q_null.topLeftCorner(width, r - rho);
    Q.setZero();
    SetIdentity(Q.bottomRows(r - rho));
    for (int j = rho - 1; j >= rho1; --j) {
      ReflectLeft(Q.bottomRows(r - j), mt.col(j).tail(r - j - 1), w.hcoeffs[j]);
    }
    auto product = w.Z_null.topLeftCorner(n, r - rho);
    product.noalias() = Z_blk.rightCols(width) * Q;
    Z_blk.rightCols(r - rho) = product;
    return;
  }
  ReflectSequenceRight(Z_blk, mt, w.hcoeffs, rho1, rho);
}

// Whether the structure kept from the last solve still holds for this level: as many rows, and
// its group's rows zero outside S.
bool StructureStillHolds(const Impl& w, int n, int m) {
  if (w.structure_m1 == 0 || w.structure_m != m) return false;
  for (int k = w.structure_s; k < n; ++k) {
    const double* a = w.A.data() + w.order[k] * w.A.outerStride();
    for (int i = 0; i < w.structure_m1; ++i) {
      if (a[w.structure_perm[i]] != 0.0) return false;
    }
  }
  return true;
}

// Finds the structure of the level's m rows anew (see FirstLevelStructure) into the kept one
// (structure_*, order); false, and none kept, when the level has none worth using.
bool FindStructure(Impl& w, int n, int m) {
  w.structure_m1 = 0;
  // Column-wise passes over A (column-major), on raw rows of 64-bit flags so that the compiler
  // vectorizes them: nonzeros per row, then S, then the rows' nonzeros outside S.
  const Eigen::Index lda = w.A.outerStride();
  std::int64_t* count = w.row_count.data();    // per row: nonzeros, then nonzeros outside S
  std::int64_t* sparse = w.row_sparse.data();  // per row: all ones if it leaves out half
  std::fill(count, count + m, 0);
  for (int c = 0; c < n; ++c) {
    const double* a = w.A.data() + c * lda;
    for (int i = 0; i < m; ++i) count[i] += a[i] != 0.0;
  }
  for (int i = 0; i < m; ++i) sparse[i] = 2 * count[i] <= n ? -1 : 0;
  int size = 0;
  for (int c = 0; c < n; ++c) {
    const double* a = w.A.data() + c * lda;
    std::int64_t touched = 0;
    for (int i = 0; i < m; ++i) touched |= (a[i] != 0.0 ? -1 : 0) & sparse[i];
    w.in_group[c] = touched != 0;
    size += touched != 0;
  }
  if (size == 0 || size + 4 > n) return false;  // no sparse row, or too little to gain
  std::fill(count, count + m, 0);
  for (int c = 0; c < n; ++c) {
    if (w.in_group[c]) continue;
    const double* a = w.A.data() + c * lda;
    for (int i = 0; i < m; ++i) count[i] += a[i] != 0.0;
  }
  // The rows' order: the group's (no nonzero outside S), then the others. order: S, then the
  // rest.
  int m1 = 0;
  for (int i = 0; i < m; ++i) m1 += count[i] == 0;
  if (m1 == 0) return false;
  for (int i = 0, k1 = 0, k2 = m1; i < m; ++i) {
    w.structure_perm[count[i] == 0 ? k1++ : k2++] = i;
  }
  for (int c = 0, k = 0, k2 = size; c < n; ++c) w.order[w.in_group[c] ? k++ : k2++] = c;
  w.structure_m = m;
  w.structure_m1 = m1;
  w.structure_s = size;
  return true;
}

// The first level with equality rows (Z = I so far) when some of its rows touch few coordinates
// (a foot's Jacobian: the free flyer and one leg). S = the coordinates touched by the rows that
// leave out at least half of them; the group = the rows within S. When the group is not empty
// and S is not nearly everything, Z becomes P (columns e_order[k], S first) and the group's rows
// are put first in perm; returns the group's size m1 and writes s = |S| (0: no structure, Z and
// perm untouched). PivotedQr and RotateBasis then work on s coordinates for the group.
// What makes the grouped factorization exact is only that the group's rows are zero outside S;
// S being the smallest such set is a matter of speed. So the last tick's structure (a humanoid's
// feet: the same Jacobian pattern from tick to tick) is reused when the level has as many rows
// and its group's rows are still zero outside S — m1 (n - s) reads instead of three passes over
// the level (~1 µs of a 30 µs solve on the humanoid).
int FirstLevelStructure(Impl& w, int n, int m, int* s) {
  *s = 0;
  if (!StructureStillHolds(w, n, m) && !FindStructure(w, n, m)) return 0;
  std::copy(w.structure_perm.begin(), w.structure_perm.begin() + m, w.perm.begin());
  w.Z.setZero();
  for (int k = 0; k < n; ++k) w.Z(w.order[k], k) = 1.0;
  *s = w.structure_s;
  return w.structure_m1;
}

bool Inside(double value, double lo, double hi, double tol) {
  return value >= lo - tol && value <= hi + tol;
}

double CarriedValue(const Impl& w, int i, const Eigen::VectorXd& x) {
  return w.g_col[i] >= 0 ? x[w.g_col[i]] : w.G.row(i).dot(x);
}

bool CarriedFeasible(const Impl& w, const Eigen::VectorXd& x, double tol) {
  for (int i = 0; i < w.num_carried; ++i) {
    if (!Inside(CarriedValue(w, i, x), w.glo[i], w.ghi[i], tol)) return false;
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

// A level whose rows outnumber the remaining DoF (m >= r; a humanoid's posture: 32 rows on 11 DoF)
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
// FactorGram: w.Gram (its lower triangle) holds M^T M and w.g1 = -M^T c; on success H1 holds
// its Cholesky factor, Gram all of it (the QP fallback reads it), u the step in u.
bool FactorGram(Impl& w, int r, double floor, const HierarchyOptions& options) {
  auto G = w.Gram.topLeftCorner(r, r);
  auto H = w.H1.topLeftCorner(r, r);
  H.triangularView<Eigen::Lower>() = G.triangularView<Eigen::Lower>();
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(H);  // in place: no allocation
  if (llt.info() != Eigen::Success) return false;
  const double smallest = H.diagonal().cwiseAbs().minCoeff(),
               largest = H.diagonal().cwiseAbs().maxCoeff();
  if (options.damping > 0.0) floor = std::max(floor, options.damping_threshold);
  if (!(smallest >= floor && largest <= 100.0 * smallest)) return false;
  for (int i = 0; i < r; ++i) {
    for (int j = i + 1; j < r; ++j) G(i, j) = G(j, i);
  }
  w.u.head(r) = -w.g1.head(r);
  llt.solveInPlace(w.u.head(r));
  return true;
}

bool GramLevel(Impl& w, const Eigen::Ref<const Eigen::MatrixXd>& mt, int m, double row_scale,
               const HierarchyOptions& options) {
  const int r = static_cast<int>(mt.rows());
  auto G = w.Gram.topLeftCorner(r, r);
  G.setZero();
  G.selfadjointView<Eigen::Lower>().rankUpdate(mt);
  w.g1.head(r).noalias() = -mt * w.cperm.head(m);  // mt's column i is row perm[i] of A
  return FactorGram(w, r, options.damping > 0.0 ? 0.0 : 1e-4 * std::sqrt(row_scale), options);
}

// A basis read without forming it: F Q [0_offset; I], F = Z's columns [off, off + rf) (formed)
// and Q = H_0 ... H_{k-1} the reflectors in Mt (ApplyReflectors; the first rho1 a group of s
// rows). Z_blk read through the pending rotation of a level above (offset = its ρ), or Z_blk
// itself (k = 0); a QR level's QP coordinates: Z_blk and its own reflectors (offset 0).
struct BasisRead {
  int off, rf, k, rho1, s, offset;
};

// F, the formed block of a BasisRead.
Eigen::Block<const Eigen::MatrixXd, Eigen::Dynamic, Eigen::Dynamic, true> Formed(
    const Impl& w, const BasisRead& b) {
  return w.Z.middleCols(b.off, b.rf);
}

// y (rf) <- Q [0; u]: a point or step u of the basis in F's coordinates.
void ToBasis(const Impl& w, const BasisRead& b, const Eigen::Ref<const Eigen::VectorXd>& u,
             Eigen::VectorXd& y) {
  y.head(b.offset).setZero();
  y.segment(b.offset, b.rf - b.offset) = u;
  ApplyReflectors(w, b.k, b.rho1, b.s, y.head(b.rf), /*transpose=*/false);
}

// A Gram level (see GramLevel) of unit rows on distinct coordinates that leave out fewer than
// they cover (a posture: all joints but the free flyer's 6), read through the pending rotation
// (b): Z_blk's columns being orthonormal,
//   M^T M = Σ_{c covered} z_c z_c^T = I - Y^T Y,  Y = Z_blk's rows at the coordinates left out,
// and those rows, M^T c and the step Z_blk u go through the reflectors as few rows and vectors.
// Z_blk is never formed (on the humanoid's reference stack, the hands level's rotation, 38 x 23
// by 12 reflectors, was the solve's largest cost; nothing below a Gram level reads Z). The
// factor is accepted only when its diagonal is >= 0.02 (the damping threshold's default): the
// cancellation in I - Y^T Y (~1e-16) is then below 1e-12 of its smallest curvature.
bool GramFromComplement(Impl& w, const BasisRead& b, int m, int r,
                        const HierarchyOptions& options) {
  const int n = static_cast<int>(w.Z.rows()), left_out = n - m;
  if (left_out >= m || b.rf - b.offset != r) return false;
  std::fill(w.covered.begin(), w.covered.end(), 0);
  for (int i = 0; i < m; ++i) {
    if (w.covered[w.a_col[i]]) return false;  // a repeated row: not a sum over coordinates
    w.covered[w.a_col[i]] = 1;
  }
  const auto F = Formed(w, b);
  auto X = w.Ycomp.topLeftCorner(left_out, b.rf);
  for (int c = 0, k = 0; c < n; ++c) {
    if (!w.covered[c]) X.row(k++) = F.row(c);
  }
  if (b.k > 0) ReflectSequenceRight(X, w.Mt, w.hcoeffs, 0, b.k);
  // G = I - Y^T Y, lower triangle (a loop: Eigen's rank update costs more in dispatch at 11 x 6).
  const auto Y = X.rightCols(r);
  auto G = w.Gram.topLeftCorner(r, r);
  for (int j = 0; j < r; ++j) {
    for (int i = j; i < r; ++i) G(i, j) = (i == j ? 1.0 : 0.0) - Y.col(i).dot(Y.col(j));
  }
  // -M^T c = -[0 I] Q^T F^T e, e = Σ_i c_i e_{col_i} (an n-vector: one product with F^T, whose
  // columns are contiguous).
  auto e = w.y_step.head(n);
  e.setZero();
  for (int i = 0; i < m; ++i) e[w.a_col[i]] = w.c[i];
  auto t = w.y_point.head(b.rf);
  t.noalias() = F.transpose() * e;
  ApplyReflectors(w, b.k, b.rho1, b.s, t, /*transpose=*/true);
  w.g1.head(r) = -t.tail(r);
  if (!FactorGram(w, r, 0.02, options)) return false;
  ToBasis(w, b, w.u.head(r), w.y_point);
  w.x.noalias() += F * w.y_point.head(b.rf);
  return true;
}

// Least squares min ||R1^T y - cperm||² + μ²||y||² with R1 = upper part of mt's first ρ rows
// (ρ x m). Plain triangular solve when full row rank and undamped. Otherwise, when the system
// is well conditioned, its normal equations (R1 R1^T + μ² I) y = R1 cperm by Cholesky (half the
// cost of the QR of [R1^T; μ I] for a humanoid's posture level, m = 32 rows on ρ = 11 DoF): their
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
    auto U = w.R1.topLeftCorner(rho, m);  // (scratch)
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
      ReflectLeft(B.bottomRightCorner(mb - j, rho - j - 1), B.col(j).tail(mb - j - 1), tau);
    }
    ReflectLeft(w.d.segment(j, mb - j), B.col(j).tail(mb - j - 1), tau);
  }
  w.y.head(rho) = w.d.head(rho);
  B.topLeftCorner(rho, rho).triangularView<Eigen::Upper>().solveInPlace(w.y.head(rho));
}

// ---------------------------------------------------------------------------------------------
// The level's QP. Variables: ũ (r), the coordinates of the rotated basis Z_blk Q (v = x_old +
// Z_blk Q ũ, Q = H_0 ... H_{ρ-1} the level's reflectors; Q = I for a Gram level), and one
// slack s_j per inequality row of the level's own:
//   min ½ ũ^T H ũ + g^T ũ + ½ ||s||²
//   s.t. lo_t <= val_t + d_t^T ũ <= hi_t              (carried rows t)
//        lo_j <= val_j + d_j^T ũ - s_j <= hi_j        (the level's rows j)
// with d = Q^T Z_blk^T (row)^T, val the row's value at x_old, and
//   H = blockdiag(R1 R1^T + μ² I_ρ, ε I_{r-ρ}),  g = [-R1 cperm; 0]
// (ũ_1: the level's objective directions after the rotation, ũ_2 the ones it does not see; a
// Gram level: H = M^T M, g = -M^T c, ρ = r, unrotated). ε = qp_regularization (0: exact).
// The carried rows' bounds are widened to include val (rounding above may leave x_old 1e-15
// outside them); a carried row the levels above fixed (|d| ~ 0) is left out.
//
// Solved by a primal active-set method (Nocedal & Wright 2006 §16.5), every iterate feasible.
// A working set W fixes some rows at one of their bounds. For the level's own rows in W the
// slack is then determined (s_j = val_j + d_j^T ũ - bound_j) and enters the objective as
// ½ (d_j^T ũ - β_j)², β_j = bound_j - val_j: so with K = H + Σ_{j in W} d_j d_j^T and
// g_W = g - Σ_{j in W} d_j β_j the equality QP of W is
//   min ½ ũ^T K ũ + g_W^T ũ   s.t.  d_t^T ũ = β_t  (carried rows t in W)
// solved by its Schur complement: S λ = β + A^T K^-1 g_W, S = A^T K^-1 A, ũ = K^-1 (A λ - g_W),
// A = [d_t]. K is H (block diagonal: cheap) while no own row is in W, else formed and factored.
// A point is the QP's optimum (the QP is strictly convex: unique) iff the KKT conditions hold
// (Nocedal & Wright Thm 16.4): every row within its bounds, every carried row of W with a
// multiplier of the sign of its bound (λ <= 0 at an upper bound, >= 0 at a lower one),
// every own row of W with a slack of that sign (s >= 0 at an upper bound: the row is violated
// there, not merely touching it); stationarity holds by construction. Verify() checks exactly
// that on the point a working set gives; nothing else is accepted.
//
// The rotated basis Z_blk Q is never formed (it cost as much as the rest of the QP: 38 x 23 by
// 12 reflectors on a humanoid's hand level), nor, for a Gram level read through the pending
// rotation of the level above (GramFromComplement), Z_blk itself: the QP is read through a
// formed block F of Z and reflectors, y = Q [0; ũ] (QpShape), v = x_old + F y. A row's
// direction in ũ (d = [0 I] Q^T F^T row^T) is formed only when the row joins W or eiquadprog
// reads every row; the other rows' values and slopes are read in y (ToBasis).

struct QpShape {
  int r, rho, nc, mi;
  double eps;
  // ũ's basis: a QR level's Z_blk and its own reflectors, a Gram level's Z_blk as it reads it
  // (through the pending rotation or not). The rows' D is in its F's coordinates.
  BasisRead basis;
};

// Dq.col(t) = [0 I] Q^T D.col(t), row t's direction in ũ, formed once per level. Where Q is not
// square (offset > 0) the row's norm in ũ is known only then: so is whether it is live.
void FormQpDirection(Impl& w, const QpShape& q, int t) {
  if (w.dq_formed[t]) return;
  const BasisRead& b = q.basis;
  auto y = w.y_step.head(b.rf);
  y = w.D.col(t).head(b.rf);
  ApplyReflectors(w, b.k, b.rho1, b.s, y, /*transpose=*/true);
  w.Dq.col(t).head(q.r) = y.tail(q.r);
  w.dq_formed[t] = 1;
  if (w.row_live[t] == kLiveUnknown) {
    w.row_live[t] = w.Dq.col(t).head(q.r).squaredNorm() > w.live_threshold[t];
  }
}

// The rows of the level's QP (see above): D.col(t) (their directions in F's coordinates: F^T
// row^T), row_val, row_lo, row_hi, row_live, qp_scale; carried rows first (nc), then the
// level's own (mi).
void PrepareRows(Impl& w, const QpShape& q, double rank_tolerance) {
  const int nc = w.num_carried;
  const auto F = Formed(w, q.basis);
  w.qp_scale = 0.0;
  for (int t = 0; t < nc + q.mi; ++t) {
    const bool own = t >= nc;
    const int i = own ? t - nc : t;
    const int col = own ? w.c_col[i] : w.g_col[i];
    auto d = w.D.col(t).head(q.basis.rf);
    double value, norm2 = 1.0;
    if (col >= 0) {
      d = F.row(col).transpose();
      value = w.x_old[col];
    } else {
      const auto row = own ? w.C.row(i) : w.G.row(i);
      d.noalias() = F.transpose() * row.transpose();
      value = row.dot(w.x_old);
      norm2 = std::max(1.0, row.squaredNorm());  // the rank threshold's scale, as for A
    }
    w.row_val[t] = value;
    w.dq_formed[t] = 0;
    // A row the levels above fixed (what is left of it in the remaining freedom is below the
    // rank tolerance) cannot move: left out (an own row keeps its violation as its slack).
    // Its norm in ũ is its norm in y when Q is square; otherwise it is known when its
    // direction is formed (at once for own rows). qp_scale: the largest squared norm of a
    // live row (in y, an upper bound, for rows whose norm in ũ is not known).
    w.live_threshold[t] = rank_tolerance * rank_tolerance * norm2;
    w.row_live[t] = q.basis.offset == 0 ? d.squaredNorm() > w.live_threshold[t] : kLiveUnknown;
    if (own) FormQpDirection(w, q, t);
    if (w.row_live[t]) w.qp_scale = std::max(w.qp_scale, d.squaredNorm());
    if (own) {
      w.row_lo[t] = w.clo[i];
      w.row_hi[t] = w.chi[i];
    } else {
      w.row_lo[t] = std::min(w.glo[i], value);
      w.row_hi[t] = std::max(w.ghi[i], value);
    }
  }
}

// The level's objective (H, g above): H1 (ρ x ρ) factored in place (its unfactored copy in
// Hfull for a working set with own rows), g1. A Gram level has set both (ρ = r). False if
// R1 R1^T is not positive definite.
bool PrepareObjective(Impl& w, int r, int m, int rho, double mu, double eps) {
  auto Hf = w.Hfull.topLeftCorner(r, r);
  if (w.gram) {
    Hf = w.Gram.topLeftCorner(r, r);
    w.qp_scale = std::max(w.qp_scale, Hf.diagonal().maxCoeff());
    return true;  // (H1 = its Cholesky factor, g1: GramLevel)
  }
  Hf.setZero();
  Hf.diagonal().tail(r - rho).setConstant(eps);
  if (rho == 0) return true;
  // R1 = the upper part of Mt's first ρ rows; H1 = R1 R1^T + μ² I and g1 = -R1 cperm as loops on
  // it (Eigen's matrix product of a 12 x 12 triangle costs more in dispatch and packing).
  const auto R1 = w.Mt.topLeftCorner(rho, m);
  auto H1 = w.H1.topLeftCorner(rho, rho);
  for (int j = 0; j < rho; ++j) {
    for (int i = j; i < rho; ++i) {
      double sum = i == j ? mu * mu : 0.0;
      for (int k = i; k < m; ++k) sum += R1(i, k) * R1(j, k);
      H1(i, j) = Hf(i, j) = Hf(j, i) = sum;
    }
  }
  w.qp_scale = std::max(w.qp_scale, H1.diagonal().maxCoeff());
  // R1 has full row rank (the pivoted QR stopped at the rank tolerance), so H1 is positive
  // definite; only if rounding says otherwise is it raised by 1e-12 (a bias of that order).
  Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(H1);  // in place: no allocation
  if (llt.info() != Eigen::Success) {
    H1 = Hf.topLeftCorner(rho, rho);
    H1.diagonal().array() += 1e-12;
    Hf.topLeftCorner(rho, rho) = H1;
    llt.compute(H1);
    if (llt.info() != Eigen::Success) return false;
  }
  for (int i = 0; i < rho; ++i) {
    double sum = 0.0;
    for (int k = i; k < m; ++k) sum += R1(i, k) * w.cperm[k];
    w.g1[i] = -sum;
  }
  return true;
}

// u <- H^-1 u (H block diagonal: H1's Cholesky factor, then 1/ε).
void ApplyKInverse(const Impl& w, const QpShape& q, bool, Eigen::Ref<Eigen::VectorXd> u) {
  if (q.rho > 0) {
    const auto L = w.H1.topLeftCorner(q.rho, q.rho);
    L.triangularView<Eigen::Lower>().solveInPlace(u.head(q.rho));
    L.triangularView<Eigen::Lower>().transpose().solveInPlace(u.head(q.rho));
  }
  u.tail(q.r - q.rho) /= q.eps;
}

double Bound(const Impl& w, int t, int side) { return side > 0 ? w.row_hi[t] : w.row_lo[t]; }

// Solves M z = b in place for M symmetric positive semidefinite (m x m, overwritten) and b in
// its range, by Cholesky with symmetric pivoting (Golub & Van Loan 2013 Alg. 4.2.4, LAPACK
// dpstrf): pivots below 1e-14 x the largest diagonal entry (or the QP's scale) end it — about
// 100 x the rounding of M; the coordinates left (M's null space: directions neither the
// level's objective nor W's rows see, ε = 0) get 0, one of the solutions, all equally
// optimal. (A small but real curvature cut there would leave the point non-stationary:
// Verify checks stationarity, so it would be rejected, not accepted.)
void SemidefiniteSolve(Impl& w, Eigen::Ref<Eigen::MatrixXd> M, Eigen::Ref<Eigen::VectorXd> b,
                       double cut = 1e-14) {
  const int m = static_cast<int>(M.rows());
  std::vector<int>& perm = w.chol_perm;
  for (int i = 0; i < m; ++i) perm[i] = i;
  // (relative to the QP's scale too: a matrix of rounding noise has no positive pivot)
  const double largest = std::max(m > 0 ? M.diagonal().maxCoeff() : 0.0, w.qp_scale);
  int rank = 0;
  for (int j = 0; j < m; ++j) {
    int p = j;
    for (int i = j + 1; i < m; ++i) {
      if (M(i, i) > M(p, p)) p = i;
    }
    if (!(M(p, p) > cut * largest)) break;
    if (p != j) {  // symmetric swap of j and p in the lower triangle (trailing part)
      M.row(j).head(j).swap(M.row(p).head(j));
      std::swap(M(j, j), M(p, p));
      for (int i = j + 1; i < p; ++i) std::swap(M(i, j), M(p, i));
      M.col(j).tail(m - p - 1).swap(M.col(p).tail(m - p - 1));
      std::swap(perm[j], perm[p]);
      std::swap(b[j], b[p]);
    }
    const double d = std::sqrt(M(j, j));
    M(j, j) = d;
    M.col(j).tail(m - j - 1) /= d;
    M.bottomRightCorner(m - j - 1, m - j - 1)
        .selfadjointView<Eigen::Lower>()
        .rankUpdate(M.col(j).tail(m - j - 1), -1.0);
    ++rank;
  }
  const auto L = M.topLeftCorner(rank, rank).triangularView<Eigen::Lower>();
  L.solveInPlace(b.head(rank));
  L.transpose().solveInPlace(b.head(rank));
  b.tail(m - rank).setZero();
  // Undo the pivoting: z[perm[i]] = b[i] (through w.chol_tmp).
  for (int i = 0; i < m; ++i) w.chol_tmp[perm[i]] = b[i];
  b = w.chol_tmp.head(m);
}

// The equality QP of W by the null-space method, for a dense K (w.K, full, unfactored) and
// g_W (w.hig): A = Q [R; 0] (Householder QR with column pivoting of W's kc carried rows),
// ũ = Q [y1; z] with R^T y1 = β (the rows of W hold exactly, whatever K's conditioning),
// (Q^T K Q)_22 z = -((Q^T K Q)_21 y1 + (Q^T g_W)_2), and R λ = (Q^T (K ũ + g_W))_1. Unlike
// the Schur complement, its accuracy does not degrade with ε (the Schur complement's
// condition number grows as 1/ε: with ε = 1e-10 it left W's rows 1e-6 off their bounds, and
// rows dependent on W's then seemed to block). False if W's rows are dependent.
bool NullSpaceEqp(Impl& w, const QpShape& q, int kc) {
  const int r = q.r;
  auto A = w.AW.topLeftCorner(r, kc);
  auto beta = w.beta.head(kc);
  double largest = 0.0;
  for (int j = 0; j < kc; ++j) {
    w.qr_perm[j] = j;
    largest = std::max(largest, A.col(j).norm());
  }
  for (int j = 0; j < kc; ++j) {
    int p = j;
    double best = -1.0;
    for (int i = j; i < kc; ++i) {
      const double norm = A.col(i).tail(r - j).squaredNorm();
      if (norm > best) {
        best = norm;
        p = i;
      }
    }
    if (!(std::sqrt(best) > 1e-10 * largest)) return false;  // dependent rows in W
    if (p != j) {
      A.col(j).swap(A.col(p));
      std::swap(beta[j], beta[p]);
      std::swap(w.qr_perm[j], w.qr_perm[p]);
    }
    double tau, b;
    A.col(j).tail(r - j).makeHouseholderInPlace(tau, b);
    A(j, j) = b;
    w.qr_tau[j] = tau;
    if (j + 1 < kc) {
      ReflectLeft(A.block(j, j + 1, r - j, kc - j - 1), A.col(j).tail(r - j - 1), tau);
    }
  }
  auto M = w.K.topLeftCorner(r, r);  // K, then Q^T K Q
  auto rhs = w.hig.head(r);          // g_W, then Q^T g_W
  for (int j = 0; j < kc; ++j) {
    const auto v = A.col(j).tail(r - j - 1);
    ReflectLeft(M.bottomRows(r - j), v, w.qr_tau[j]);
    ReflectRight(M.rightCols(r - j), v, w.qr_tau[j], w.work);
    ReflectLeft(rhs.tail(r - j), v, w.qr_tau[j]);
  }
  const auto R = A.topLeftCorner(kc, kc).triangularView<Eigen::Upper>();
  auto y = w.ut.head(r);  // [y1; z], then ũ
  y.head(kc) = beta;
  R.transpose().solveInPlace(y.head(kc));
  if (kc < r) {
    auto z = y.tail(r - kc);
    z = -rhs.tail(r - kc);
    z.noalias() -= M.bottomLeftCorner(r - kc, kc) * y.head(kc);
    // A cut curvature that was real (small, not rounding: a nearly flat direction the level
    // still wants to move along) leaves M22 z != b: solved again with a lower cut.
    const int m2 = r - kc;
    w.M22.topLeftCorner(m2, m2) = M.bottomRightCorner(m2, m2);
    w.b22.head(m2) = z;
    SemidefiniteSolve(w, M.bottomRightCorner(m2, m2), z);
    auto check = w.grad.head(m2);
    check = w.b22.head(m2);
    check.noalias() -= w.M22.topLeftCorner(m2, m2).selfadjointView<Eigen::Lower>() * z;
    if (check.cwiseAbs().maxCoeff() > 1e-12 * (w.b22.head(m2).cwiseAbs().maxCoeff() + 1e-300)) {
      z = w.b22.head(m2);
      SemidefiniteSolve(w, w.M22.topLeftCorner(m2, m2), z, 1e-20);
    }
  }
  // λ (pivot order) from the first kc rows of Q^T (K ũ + g_W) = M [y1; z] + rhs (M's first
  // kc rows are intact: the factorization overwrote only M22).
  auto lp = w.residual.head(kc);
  lp = rhs.head(kc);
  lp.noalias() += M.topRows(kc) * y;
  R.solveInPlace(lp);
  for (int j = 0; j < kc; ++j) w.lambda[w.qr_perm[j]] = lp[j];
  for (int j = kc - 1; j >= 0; --j) {
    ReflectLeft(y.tail(r - j), A.col(j).tail(r - j - 1), w.qr_tau[j]);
  }
  return true;
}

// The equality QP of the working set W (w.W_rows, w.W_sides) into w.ut (r), w.s_eqp (mi) and
// w.lambda (the carried rows of W, in W's order). By the Schur complement when K is H (no own
// row in W) and ε >= 1e-6 (the controller's QPs: cheap, and accurate with one refinement
// step), else by the null-space method. False if K is not positive definite or W's rows are
// dependent.
bool SolveWorkingSet(Impl& w, const QpShape& q) {
  const int r = q.r, k = static_cast<int>(w.W_rows.size());
  bool own = false;
  int kc = 0;
  for (int i = 0; i < k; ++i) {
    own |= w.W_rows[i] >= q.nc;
    kc += w.W_rows[i] < q.nc;
  }
  if (kc > r) return false;  // more fixed rows than DoF: dependent
  for (int t : w.W_rows) FormQpDirection(w, q, t);
  const bool schur = !own && q.eps >= 1e-6;
  auto g = w.hig.head(r);  // g_W
  g.setZero();
  g.head(q.rho) = w.g1.head(q.rho);
  if (!schur) {
    auto K = w.K.topLeftCorner(r, r);
    K = w.Hfull.topLeftCorner(r, r);
    for (int i = 0; i < k; ++i) {
      const int t = w.W_rows[i];
      if (t < q.nc) continue;
      const auto d = w.Dq.col(t).head(r);
      K.noalias() += d * d.transpose();
      g -= d * (Bound(w, t, w.W_sides[i]) - w.row_val[t]);
    }
  }
  kc = 0;
  for (int i = 0; i < k; ++i) {
    const int t = w.W_rows[i];
    if (t >= q.nc) continue;
    w.AW.col(kc).head(r) = w.Dq.col(t).head(r);
    w.beta[kc++] = Bound(w, t, w.W_sides[i]) - w.row_val[t];
  }
  if (!schur) {
    if (kc == 0) {
      w.ut.head(r) = -g;
      SemidefiniteSolve(w, w.K.topLeftCorner(r, r), w.ut.head(r));
    } else if (!NullSpaceEqp(w, q, kc)) {
      return false;
    }
  } else {
    ApplyKInverse(w, q, false, g);  // g <- H^-1 g_W
    w.ut.head(r) = -g;
    if (kc > 0) {
      const auto AW = w.AW.topLeftCorner(r, kc);
      auto HiA = w.HiA.topLeftCorner(r, kc);
      HiA = AW;
      for (int j = 0; j < kc; ++j) ApplyKInverse(w, q, false, HiA.col(j));
      auto S = w.S.topLeftCorner(kc, kc);
      S.noalias() = AW.transpose() * HiA;
      Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(S);
      if (llt.info() != Eigen::Success) return false;
      auto lambda = w.lambda.head(kc);
      lambda = w.beta.head(kc);
      lambda.noalias() += AW.transpose() * g;
      llt.solveInPlace(lambda);
      w.ut.head(r).noalias() += HiA * lambda;
      // One step of iterative refinement on A^T ũ = β.
      auto residual = w.residual.head(kc);
      residual = w.beta.head(kc);
      residual.noalias() -= AW.transpose() * w.ut.head(r);
      llt.solveInPlace(residual);
      w.ut.head(r).noalias() += HiA * residual;
      lambda += residual;
    }
  }
  // Slacks: determined for own rows in W, 0 for the others.
  w.s_eqp.head(q.mi).setZero();
  for (int i = 0; i < k; ++i) {
    const int t = w.W_rows[i];
    if (t < q.nc) continue;
    w.s_eqp[t - q.nc] =
        w.row_val[t] + w.Dq.col(t).head(r).dot(w.ut.head(r)) - Bound(w, t, w.W_sides[i]);
  }
  return true;
}

// How far the working set's point is from the bound side row i of W should hold, in units of
// its tolerance: for a carried row its multiplier pulling the wrong way (side λ / dual_tol),
// for an own row its slack of the wrong sign (-side s / tol). > 1: drop that row.
double WrongSign(const Impl& w, const QpShape& q, int i, int carried_index, double tol,
                 double dual_tol) {
  const int t = w.W_rows[i], side = w.W_sides[i];
  if (t < q.nc) return side * w.lambda[carried_index] / dual_tol;
  return -side * w.s_eqp[t - q.nc] / tol;
}

// KKT check of the working set's point (w.ut, w.s_eqp, w.lambda): -2 if a row is off its
// bounds by more than tol, else the index in W of the worst wrong sign (-1: none, optimal).
int Verify(Impl& w, const QpShape& q, double tol, double dual_tol) {
  const int r = q.r, nt = q.nc + q.mi, k = static_cast<int>(w.W_rows.size());
  ToBasis(w, q.basis, w.ut.head(r), w.y_point);
  const auto y = w.y_point.head(q.basis.rf);
  // The rows' values: a unit row (joint bounds) reads its coordinate of the step in v, F y (one
  // matrix-vector product, where a dot product per row cost ~1 µs on a humanoid's 32 bounds).
  const auto F = Formed(w, q.basis);
  auto dv = w.dv.head(F.rows());
  dv.noalias() = F * y;
  auto value_at = [&](int t) {
    const int col = t < q.nc ? w.g_col[t] : w.c_col[t - q.nc];
    return w.row_val[t] + (col >= 0 ? dv[col] : w.D.col(t).head(q.basis.rf).dot(y));
  };
  for (int t = 0; t < nt; ++t) {
    if (!w.row_live[t] || w.in_W[t]) continue;
    const double value = value_at(t);
    if (!Inside(value, w.row_lo[t], w.row_hi[t], tol)) {
      return -2;
    }
  }
  // Stationarity of the level's objective in the remaining freedom: H ũ + g + Σ_{own j in W}
  // s_j d_j = Σ_{carried t in W} λ_t d_t (exact for the Schur complement; the null-space
  // method's semidefinite solve may cut a curvature it took for rounding).
  auto grad = w.grad.head(r);
  grad.noalias() = w.Hfull.topLeftCorner(r, r) * w.ut.head(r);
  grad.head(q.rho) += w.g1.head(q.rho);
  double grad_scale = grad.cwiseAbs().maxCoeff();
  for (int i = 0, c = 0; i < k; ++i) {
    const int t = w.W_rows[i];
    const auto d = w.Dq.col(t).head(r);
    const double f = t < q.nc ? -w.lambda[c++] : w.s_eqp[t - q.nc];
    grad += f * d;
    grad_scale = std::max(grad_scale, std::abs(f) * d.cwiseAbs().maxCoeff());
  }
  if (grad.cwiseAbs().maxCoeff() > 1e-9 * (1.0 + grad_scale)) {
    return -2;
  }
  int worst = -1, kc = 0;
  double worst_value = 1.0;
  for (int i = 0; i < k; ++i) {
    const int t = w.W_rows[i];
    if (t < q.nc) {
      const double value = value_at(t);
      if (std::abs(value - Bound(w, t, w.W_sides[i])) > tol) {
        return -2;
      }
    }
    const double wrong = WrongSign(w, q, i, t < q.nc ? kc : -1, tol, dual_tol);
    if (t < q.nc) ++kc;
    if (wrong > worst_value) {
      worst = i;
      worst_value = wrong;
    }
  }
  return worst;
}

void ClearWorkingSet(Impl& w) {
  for (int t : w.W_rows) w.in_W[t] = 0;
  w.W_rows.clear();
  w.W_sides.clear();
}

void AddToWorkingSet(Impl& w, int t, int side) {
  w.W_rows.push_back(t);
  w.W_sides.push_back(side);
  w.in_W[t] = 1;
}

void RemoveFromWorkingSet(Impl& w, int i) {
  w.in_W[w.W_rows[i]] = 0;
  w.W_rows.erase(w.W_rows.begin() + i);
  w.W_sides.erase(w.W_sides.begin() + i);
}

// The multiplier tolerance: a wrong sign this small (1e-10 of the objective's gradient scale:
// the level's g1, or its own rows' violations) is rounding, not a direction of descent (what
// the point loses to the optimum is below that times the row's range); dropping its row would
// cycle (seen on nearly flat levels: multipliers of 1e-11 changing sign with rounding).
double DualTolerance(const Impl& w, const QpShape& q) {
  double scale = q.rho > 0 ? w.g1.head(q.rho).cwiseAbs().maxCoeff() : 0.0;
  for (int j = 0; j < q.mi; ++j) {
    const int t = q.nc + j;
    scale = std::max(scale,
                     std::abs(w.row_val[t] - std::clamp(w.row_val[t], w.row_lo[t], w.row_hi[t])));
  }
  return 1e-10 * (1.0 + scale);
}

// Tries the working set in w.W_rows: accepted (true) only if its point verifies.
bool TryWorkingSet(Impl& w, const QpShape& q, double tol) {
  return SolveWorkingSet(w, q) && Verify(w, q, tol, DualTolerance(w, q)) == -1;
}

// The primal active-set method from ũ = 0 (feasible: the carried bounds include x_old) with
// the level's violated rows in W (s = their violation, so they are feasible too). Each
// iteration steps towards the working set's point up to the first row that blocks (it joins
// W; a row whose slope is rounding, e.g. dependent on W's rows, never blocks), or takes the
// full step and drops the row of the worst wrong sign; optimal when none is wrong. Leaves the
// last (feasible) iterate in w.u (ũ) and w.s_cur, also on failure (S singular, cycling).
bool PrimalActiveSet(Impl& w, const QpShape& q, double tol) {
  const int r = q.r, nt = q.nc + q.mi;
  auto u = w.u.head(r);
  auto s = w.s_cur.head(q.mi);
  u.setZero();
  ClearWorkingSet(w);
  for (int j = 0; j < q.mi; ++j) {
    const int t = q.nc + j;
    s[j] = w.row_val[t] - std::clamp(w.row_val[t], w.row_lo[t], w.row_hi[t]);
    if (s[j] != 0.0 && w.row_live[t]) AddToWorkingSet(w, t, s[j] > 0.0 ? 1 : -1);
  }
  const double dual_tol = DualTolerance(w, q);
  const int max_iterations = 3 * (r + nt) + 10;
  // A carried row that blocked the last step but is a combination of W's carried rows up to
  // rounding (its slope along the step above the slope test's rounding, yet its direction
  // within 1e-10 of span(W): repeated or dependent tasks at a degenerate vertex) makes W
  // dependent. The rows it depends on hold it where it is in exact arithmetic, so it leaves W
  // and is not tried again until a row leaves W (Verify checks it at the end either way).
  std::fill(w.implied.begin(), w.implied.begin() + nt, 0);
  int joined = -1;
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    const bool solved = SolveWorkingSet(w, q);
    if (!solved && joined >= 0 && joined < q.nc) {
      RemoveFromWorkingSet(w, static_cast<int>(w.W_rows.size()) - 1);
      w.implied[joined] = 1;
      joined = -1;
      continue;
    }
    joined = -1;
    if (!solved) {
      return false;
    }
    auto p = w.dx.head(r);  // the step in ũ; in s: s_eqp - s
    p = w.ut.head(r) - u;
    const double p_norm = p.cwiseAbs().maxCoeff();
    // A step of rounding size (the working set's point is the current one) blocks nothing.
    const bool moves = p_norm > 1e-13 * (1.0 + u.cwiseAbs().maxCoeff()) ||
                       (w.s_eqp.head(q.mi) - s).cwiseAbs().maxCoeff() > 1e-13;
    double alpha = 1.0;
    int blocking = -1, blocking_side = 0;
    // The rows' values at u and slopes along p, read in F's coordinates.
    ToBasis(w, q.basis, u, w.y_point);
    ToBasis(w, q.basis, p, w.step);
    const auto yu = w.y_point.head(q.basis.rf), yp = w.step.head(q.basis.rf);
    const double yp_norm = yp.cwiseAbs().maxCoeff();
    for (int t = 0; moves && t < nt; ++t) {
      if (!w.row_live[t] || w.in_W[t] || w.implied[t]) continue;
      const auto d = w.D.col(t).head(q.basis.rf);
      double value = w.row_val[t] + d.dot(yu), slope = d.dot(yp);
      double scale = d.cwiseAbs().maxCoeff() * yp_norm;
      if (t >= q.nc) {
        const int j = t - q.nc;
        value -= s[j];
        slope -= w.s_eqp[j] - s[j];
        scale += std::abs(w.s_eqp[j] - s[j]);
      }
      // A row the step moves by less than a tenth of the tolerance (or by rounding: a row
      // dependent on W's, which the step keeps in exact arithmetic; 1e-10 of the step: the
      // dependence test of NullSpaceEqp) does not block.
      if (std::abs(slope) <= std::max(1e-10 * scale, 0.1 * tol)) continue;
      double step = 1.0;
      int side = 0;
      if (slope > 0.0 && !std::isinf(w.row_hi[t])) {
        step = (w.row_hi[t] - value) / slope;
        side = 1;
      } else if (slope < 0.0 && !std::isinf(w.row_lo[t])) {
        step = (w.row_lo[t] - value) / slope;
        side = -1;
      }
      if (side != 0 && step < alpha) {
        FormQpDirection(w, q, t);  // (whether it is live, if not known yet)
        if (!w.row_live[t]) continue;
        alpha = std::max(step, 0.0);
        blocking = t;
        blocking_side = side;
      }
    }
    if (blocking >= 0) {
      u.noalias() += alpha * p;
      s += alpha * (w.s_eqp.head(q.mi) - s);
      AddToWorkingSet(w, blocking, blocking_side);
      joined = blocking;
      continue;
    }
    u = w.ut.head(r);
    s = w.s_eqp.head(q.mi);
    const int wrong = Verify(w, q, tol, dual_tol);
    if (wrong == -1) return true;
    if (wrong == -2) return false;
    RemoveFromWorkingSet(w, wrong);
    std::fill(w.implied.begin(), w.implied.begin() + nt, 0);  // W's span shrank
  }
  return false;
}

// One QP for the level by eiquadprog's dual active-set method (Goldfarb–Idnani, TSID's QP),
// the fallback when the primal method fails (degenerate working sets): variables (ũ (r),
// s (mi)), the same objective and rows. Returns false on failure; else its point in qp.z (and
// w.ut / w.s_eqp); its working set, to be verified, is then read by WorkingSetAtBounds.
bool SolveLevelQp(Impl& w, Impl::LevelQp& qp, const QpShape& q, HierarchyReport* report) {
  const int r = q.r, n = static_cast<int>(w.Z.rows()), nt = q.nc + q.mi;
  const int slack0 = n;  // slack variables follow the (padded) ũ
  for (int t = 0; t < nt; ++t) {
    if (w.row_live[t]) FormQpDirection(w, q, t);
  }
  qp.H.setZero();
  qp.g.setZero();
  qp.H.topLeftCorner(r, r) = w.Hfull.topLeftCorner(r, r);
  // (strictly convex, as the dual method needs: the exact cascade's ε = 0 raised to 1e-9; its
  // point only proposes a working set, verified on the QP itself)
  for (int i = q.rho; i < r; ++i) qp.H(i, i) = std::max(qp.H(i, i), 1e-9);
  qp.H.diagonal().segment(r, n - r).setOnes();      // unused padding
  qp.H.diagonal().tail(qp.H.rows() - n).setOnes();  // ½||s||² (and unused slacks)
  qp.g.head(q.rho) = w.g1.head(q.rho);
  qp.CI.setZero();
  qp.ci0.setOnes();  // padding rows: 1 >= 0
  // lo <= val + a·z <= hi as  a·z + (val - lo) >= 0  and  -a·z + (hi - val) >= 0.
  for (int t = 0; t < nt; ++t) {
    if (!w.row_live[t]) continue;
    Eigen::VectorXd& a = qp.row;
    a.setZero();
    a.head(r) = w.Dq.col(t).head(r);
    if (t >= q.nc) a[slack0 + t - q.nc] = -1.0;
    if (!std::isinf(w.row_lo[t])) {
      qp.CI.row(2 * t) = a.transpose();
      qp.ci0[2 * t] = w.row_val[t] - w.row_lo[t];
    }
    if (!std::isinf(w.row_hi[t])) {
      qp.CI.row(2 * t + 1) = -a.transpose();
      qp.ci0[2 * t + 1] = w.row_hi[t] - w.row_val[t];
    }
  }
  const auto status = qp.solver.solve_quadprog(qp.H, qp.g, qp.CE, qp.ce0, qp.CI, qp.ci0, qp.z);
  report->last_qp_status = static_cast<int>(status);
  report->last_qp_iterations = qp.solver.getIteratios();
  if (status != third_party::eiquadprog::solvers::EIQUADPROG_FAST_OPTIMAL || !qp.z.allFinite())
    return false;
  w.ut.head(r) = qp.z.head(r);
  w.s_eqp.head(q.mi) = qp.z.segment(slack0, q.mi);
  return true;
}

// W <- the rows within 1e-9 of a bound at eiquadprog's point (qp.z: ũ, then the slacks).
void WorkingSetAtBounds(Impl& w, const Impl::LevelQp& qp, const QpShape& q) {
  const int r = q.r, nt = q.nc + q.mi, slack0 = static_cast<int>(w.Z.rows());
  ClearWorkingSet(w);
  for (int t = 0; t < nt; ++t) {
    if (!w.row_live[t]) continue;
    double value = w.row_val[t] + w.Dq.col(t).head(r).dot(qp.z.head(r));
    if (t >= q.nc) value -= qp.z[slack0 + t - q.nc];
    const double scale = 1e-9 * (1.0 + std::abs(value));
    if (std::abs(value - w.row_hi[t]) <= scale) {
      AddToWorkingSet(w, t, 1);
    } else if (std::abs(value - w.row_lo[t]) <= scale) {
      AddToWorkingSet(w, t, -1);
    }
  }
}

// A row PrepareRows left out as fixed (its direction in the remaining freedom below the rank
// tolerance) still moves by that direction times the step, and a QP step along a direction of
// no curvature can be long enough (1e10 on a near-singular arm) to move it by O(1): a carried
// row then breaks a level above, an own row changes its slack unseen. Such rows, moved by more
// than the tolerance at the QP's point w.x, are put back (row_live); true if any was.
bool ReviveMovedRows(Impl& w, int mi, double tol) {
  bool revived = false;
  for (int t = 0; t < w.num_carried + mi; ++t) {
    if (w.row_live[t]) continue;
    const double value =
        t >= w.num_carried ? RowValue(w, t - w.num_carried, w.x) : CarriedValue(w, t, w.x);
    if (std::abs(value - w.row_val[t]) > tol) w.row_live[t] = revived = true;
  }
  return revived;
}

// Solves the level's QP (after PrepareRows / PrepareObjective) into w.x; records the working
// set as the next tick's first guess. Returns how: 0 the active-set shortcut (warm guess or primal
// iterations), 1 eiquadprog (its working set verified; with the shortcut off, an unverified
// eiquadprog point is repaired by the primal iterations, still not the shortcut), -1 none
// verified (w.x = the primal method's last iterate: feasible, not proven optimal).
int SolveQp(Impl& w, int level, const QpShape& q, bool shortcut, double tol,
            HierarchyReport* report) {
  const auto F = Formed(w, q.basis);
  auto accept = [&]() {
    ToBasis(w, q.basis, w.ut.head(q.r), w.y_point);
    w.x = w.x_old;
    w.x.noalias() += F * w.y_point.head(q.basis.rf);
    w.active[level].clear();
    for (size_t i = 0; i < w.W_rows.size(); ++i)
      w.active[level].emplace_back(w.W_rows[i], w.W_sides[i]);
    ClearWorkingSet(w);
  };
  auto eiquadprog = [&]() {
    if (!SolveLevelQp(w, *w.qps[level], q, report)) return false;
    WorkingSetAtBounds(w, *w.qps[level], q);
    return TryWorkingSet(w, q, tol);
  };
  auto primal = [&]() { return PrimalActiveSet(w, q, tol); };
  if (shortcut) {
    ClearWorkingSet(w);
    const int nt = q.nc + q.mi;
    for (const auto& [t, side] : w.active[level]) {
      if (t >= nt) continue;
      FormQpDirection(w, q, t);
      if (w.row_live[t] && !w.in_W[t] && !std::isinf(Bound(w, t, side))) {
        AddToWorkingSet(w, t, side);
      }
    }
    if (!w.W_rows.empty() && TryWorkingSet(w, q, tol)) {
      accept();
      return 0;
    }
    if (primal()) {
      accept();
      return 0;
    }
    if (eiquadprog()) {
      accept();
      return 1;
    }
  } else {
    if (eiquadprog()) {
      accept();
      return 1;
    }
    if (primal()) {  // eiquadprog's point not verified: repaired by the primal iterations
      accept();
      return 1;
    }
  }
  // Nothing verified: the primal method's last iterate, feasible whatever its outcome.
  ClearWorkingSet(w);
  w.active[level].clear();
  ToBasis(w, q.basis, w.u.head(q.r), w.y_point);
  w.x = w.x_old;
  w.x.noalias() += F * w.y_point.head(q.basis.rf);
  return -1;
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
  SetIdentity(w.Z);
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
    // max(1, largest |row of A|)²: the rank threshold is relative to it, and absolute for rows
    // under 1 (a row of norm 1e-11 is rounding, not a task that should lock a joint).
    double row_scale = 1.0;
    for (const TaskShape& shape : hierarchy.levels()[l]) {
      const TaskTerms& t = *tasks[k++];
      const int first_row = row;
      row += shape.rows;
      if (!t.active) continue;
      // (A task's rows are copied as one block: row by row, both column-major matrices are
      // read and written with a stride.)
      const bool unit = !shape.unit_columns.empty();
      if (t.inequality) {
        if (!unit) w.C.middleRows(mi, shape.rows) = t.jacobian;
        for (int i = 0; i < shape.rows; ++i, ++mi) {
          w.c_col[mi] = unit ? shape.unit_columns[i] : -1;
          w.clo[mi] = t.lower[i];
          w.chi[mi] = t.upper[i];
        }
      } else {
        if (!unit) {
          w.A.middleRows(m, shape.rows) = t.jacobian;
          row_scale = std::max(row_scale, t.jacobian.rowwise().squaredNorm().maxCoeff());
          dense = true;
        }
        for (int i = 0; i < shape.rows; ++i, ++m) {
          w.a_col[m] = unit ? shape.unit_columns[i] : -1;
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
    auto Z_blk = w.Z.middleCols(off, r);
    // Where this level reads Z_blk from: Z_blk itself, or (a Gram level from its complement)
    // through the pending rotation, left unapplied.
    BasisRead basis{off, r, 0, 0, 0, 0};
    if (m > 0 && r > 0 && !dense && m >= r) {
      for (int i = 0; i < m; ++i) w.c[i] = w.b[i] - w.x[w.a_col[i]];
      const BasisRead through = pending.rho > 0
                                    ? BasisRead{pending.off,  pending.r,       pending.rho,
                                                pending.rho1, pending.s_group, pending.rho}
                                    : basis;
      if (GramFromComplement(w, through, m, r, options)) {
        w.gram = true;
        basis = through;
        rho = r;
        report.gram_levels[l] = true;
      }
    }
    if (m > 0 && r > 0 && !w.gram) {
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
        // u = Q [y; 0], v += Z u.
        w.u.head(r).setZero();
        w.u.head(rho) = w.y.head(rho);
        ApplyReflectors(w, rho, rho1, s_group, w.u.head(r), /*transpose=*/false);
        w.x.noalias() += Z_blk * w.u.head(r);
      }
    }
    // The unconstrained step is the cascade's solution when it keeps every inequality.
    const bool inside = CarriedFeasible(w, w.x, tol) && LevelFeasible(w, mi, w.x, tol);
    if (inside) w.active[l].clear();
    if (w.num_carried + mi > 0 && !inside) {
      if (r > 0) {
        // The QP reads Z_blk: a pending rotation is applied, unless this level reads through it.
        if (basis.k == 0) rotate_pending();
        report.qp_levels[l] = true;
        ++report.num_qp;
        // (a Gram level's QP works in u as it reads Z_blk; a QR level's in its rotated ũ)
        const QpShape q{r,
                        rho,
                        w.num_carried,
                        mi,
                        options.qp_regularization,
                        w.gram ? basis : BasisRead{off, r, rho, rho1, s_group, 0}};
        PrepareRows(w, q, options.rank_tolerance);
        int how = PrepareObjective(w, r, m, rho, report.dampings[l], q.eps)
                      ? SolveQp(w, l, q, options.active_set_shortcut, tol, &report)
                      : -1;
        if (how >= 0 && ReviveMovedRows(w, mi, tol)) {
          how = SolveQp(w, l, q, options.active_set_shortcut, tol, &report);
        }
        if (how == 0) {
          report.active_set_levels[l] = true;
          ++report.num_active_set;
        } else if (how < 0) {
          ++report.qp_failures;
        }
      }
      // r == 0: v is fixed by the levels above; the slack below records the violation.
    }
    if (rho > 0 && !w.gram) {  // (Gram: ρ = r, no null space)
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
    if (m1 > 0 && rho == 0) SetIdentity(w.Z);  // nothing was rotated: back to Z = I
    report.ranks[l] = rho;
    off += rho;
  }
  report.remaining_dof = n - off;
  *v = w.x;
}

}  // namespace marionette::sot
