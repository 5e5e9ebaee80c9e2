#pragma once
/// The strict-hierarchy solver (the algorithm; the Solver entity wraps it in the graph).
///
/// Levels l = 1..p, in decreasing priority. Each level holds equality rows  A v = b  and
/// inequality rows  lo <= C v <= hi  (a task of k rows is one or the other). The solution is
/// Kanoun's cascade (Dang 2012 eq. 2.77–2.81): with S_0 = R^nv,
///   S_l = argmin_{v ∈ S_{l-1}}  ||A_l v - b_l||² + ||s||²   s.t.  lo_l <= C_l v - s <= hi_l
/// so a lower level never changes what a higher level achieves, and inequalities of any level
/// (joint limits at level 0) keep holding below it.
///
/// Computation (Nicolin 2022 eq. 3.7–3.10, Escande et al. 2014): an orthonormal basis Z of the
/// remaining freedom (n x r, r shrinking level by level) is kept explicitly. At each level,
/// M = A Z is decomposed by a Householder QR with column pivoting of M^T (rank revealing, much
/// cheaper than an SVD); the least-squares step (damped near singularities) moves v within
/// range(Z), and Z's trailing columns are rotated onto null(M) (eq. 3.10) when a level below
/// reads them: only those columns are formed, and a QP on the level works in the rotated
/// coordinates without forming them (the reflectors are applied to the few vectors it reads).
/// Shortcuts keep that exact while cutting its cost: the first level with equality rows factors
/// its sparse rows first on the few coordinates they touch (a foot: free flyer + one leg), so
/// their reflectors rotate a small block of Z; a level whose rows outnumber the remaining DoF
/// and, well conditioned, use them all (a posture under feet and hands) is solved on its Gram
/// matrix M^T M (Cholesky) with no QR and no rotation, nothing remaining below it — and when its
/// rows are unit rows covering most coordinates (a posture on every joint), M^T M = I - Y^T Y
/// from the few rows Y of Z it leaves out, read through the rotation above, which is then never
/// formed. The unconstrained step is exact for the cascade whenever it satisfies every inequality
/// carried from above and the level's own: that is checked, and only when it fails is the level
/// solved as a QP. That QP is first tried by an active-set shortcut: the rows active at the last
/// tick (carried bounds, and the level's own inequality rows) are fixed and the equality QP solved
/// through its Schur complement; then, if needed, a primal active-set iteration from the current
/// point (Nocedal & Wright §16.5). A point is accepted only with a KKT certificate: every row
/// within its bounds, stationarity, every fixed carried row's multiplier and every fixed own
/// row's slack of the sign of its bound. The QP being strictly convex, a certified point is its
/// unique optimum, the one the QP solver below returns. Only when no point is certified (a
/// rank-deficient or ill-conditioned working set) is the level solved (in the r coordinates of
/// Z, plus one slack per inequality row) by eiquadprog's dual active-set method (Goldfarb–Idnani,
/// the QP of TSID): exact, and robust on the degenerate vertices met when many velocity bounds
/// bind at once (proxsuite, tried first, stalled or reported such feasible QPs infeasible). An
/// inequality level then carries its rows down with bounds shifted by its optimal slack s*
/// (the level's optimal set is exactly {lo + s* <= C v <= hi + s*}).
///
/// Real time: nothing is allocated; every QP is sized for its level's worst case at construction.
/// A level solved by a QP costs tens to hundreds of µs (the nominal path a few µs per level).

#include <Eigen/Core>
#include <memory>
#include <vector>

#include "marionette/sot/task.h"

namespace marionette::sot {

struct HierarchyOptions {
  /// A pivot of the QR whose remaining norm is <= rank_tolerance x max(1, the largest row norm
  /// of the level's (unprojected) Jacobian) is a dependent row (a task conflicting with higher
  /// levels, or already fixed by them): it gets no DoF. The floor of 1 makes rows of rounding
  /// size (a Jacobian row of norm 1e-11) rank 0 instead of locking a joint.
  double rank_tolerance = 1e-9;
  /// Variable damping (Maciejewski & Klein): when the level's smallest pivot d < threshold, the
  /// least squares gets μ² = damping² (1 - (d / threshold)²). 0 = undamped (exact hierarchy).
  double damping = 0.02;
  double damping_threshold = 0.02;
  /// An inequality is violated beyond this (in units of J v) before a QP is solved.
  double constraint_tolerance = 1e-9;
  /// Weight ε of ½ε||ũ_2||² added to a QP level, ũ_2 being the level's coordinates that its
  /// equality rows do not see (its null space within Z, rad/s). Without it the dual active-set
  /// method has no positive definite Hessian; with it tiny (1e-10, the exact cascade) the humanoid
  /// command chattered in closed loop once bounds bound under an unachievable level (±3.7 rad/s
  /// from tick to tick when a reach was inserted too fast, ±1 rad/s on a stretched arm); with
  /// 1e-4 the first case was smooth but not the second; with 1e-2 both were. The price: when a
  /// QP level's optimum needs motion along ũ_2 to satisfy an inequality, it moves by O(ε) (a
  /// level-1 velocity error of ~1e-7..1e-5 m/s with the feet of a humanoid). The objective
  /// directions are not regularized, and levels solved without a QP are exact. Set ~1e-10 for
  /// an exact cascade (the brute-force comparison does).
  double qp_regularization = 1e-2;
  /// Active-set iteration limit of the QP levels (eiquadprog).
  int qp_max_iterations = 1000;
  /// Try the active-set shortcut (working set of the last tick + KKT certificate) before
  /// eiquadprog on QP levels. Exact either way (a point is accepted only with the certificate
  /// that it is the QP's optimum; tests/python/sot/test_cascade_reference.py checks it against a
  /// textbook cascade); false = always eiquadprog (for comparison).
  bool active_set_shortcut = true;
};

/// Shape of a task in a hierarchy (from its TaskTerms model).
struct TaskShape {
  int rows = 0;
  bool inequality = false;
  std::vector<int> unit_columns;  ///< non-empty: row i is e_{unit_columns[i]}^T
};

/// The immutable description of a stack: nv, tasks per level, options.
class Hierarchy {
 public:
  /// Throws SotError on nv < 1, an empty task or unit columns out of range.
  Hierarchy(int nv, std::vector<std::vector<TaskShape>> levels, HierarchyOptions options = {});
  int nv() const { return nv_; }
  int num_levels() const { return static_cast<int>(levels_.size()); }
  const std::vector<std::vector<TaskShape>>& levels() const { return levels_; }
  const HierarchyOptions& options() const { return options_; }
  int num_tasks() const { return num_tasks_; }
  int max_equality_rows() const { return max_equality_rows_; }
  int max_inequality_rows() const { return max_inequality_rows_; }
  int total_inequality_rows() const { return total_inequality_rows_; }
  int total_rows() const { return total_rows_; }

 private:
  int nv_;
  std::vector<std::vector<TaskShape>> levels_;
  HierarchyOptions options_;
  int num_tasks_ = 0, max_equality_rows_ = 0, max_inequality_rows_ = 0, total_inequality_rows_ = 0,
      total_rows_ = 0;
};

/// What happened in the last solve (per level where relevant).
struct HierarchyReport {
  std::vector<int> ranks;       ///< DoF used by each level's equality rows
  std::vector<bool> qp_levels;  ///< true where the level was solved as a QP (either way)
  std::vector<bool>
      active_set_levels;          ///< true where that QP was solved by the active-set shortcut
  std::vector<bool> gram_levels;  ///< true where the level was solved on its Gram matrix (no QR)
  std::vector<double> dampings;   ///< μ used at each level (0 = undamped)
  int num_qp = 0;                 ///< QP levels in the last solve (eiquadprog or the shortcut)
  int num_active_set = 0;         ///< of which solved by the active-set shortcut
  int qp_failures = 0;      ///< QPs that did not converge (their level kept the unconstrained step)
  int remaining_dof = 0;    ///< r after the last level
  int last_qp_status = -1;  ///< eiquadprog status of the last QP (0 = optimal, 5 = a dependent row)
  int last_qp_iterations = 0;
};

/// Preallocated workspace of a Hierarchy (one per thread; reused across ticks).
class HierarchyWorkspace {
 public:
  explicit HierarchyWorkspace(const Hierarchy& hierarchy);
  ~HierarchyWorkspace();
  HierarchyWorkspace(HierarchyWorkspace&&) noexcept;
  const HierarchyReport& report() const { return report_; }
  struct Impl;  // defined in hierarchy.cc (keeps the QP solver out of this header)

 private:
  friend void SolveHierarchy(const Hierarchy&, const std::vector<const TaskTerms*>&,
                             HierarchyWorkspace*, Eigen::VectorXd*, const Eigen::VectorXd*);
  std::unique_ptr<Impl> impl_;
  HierarchyReport report_;
};

/// Solves the hierarchy. `tasks` lists the TaskTerms in level order (level 0's tasks, then
/// level 1's ...), matching `hierarchy.levels()`; inactive tasks are skipped. Writes v (nv).
/// `target_offsets` (optional, all tasks' rows stacked in the same order) is added to the
/// targets of equality rows (the Solver's smooth switching); inequality rows ignore it.
/// Throws SotError on a count or size mismatch (checked before anything is computed).
void SolveHierarchy(const Hierarchy& hierarchy, const std::vector<const TaskTerms*>& tasks,
                    HierarchyWorkspace* workspace, Eigen::VectorXd* v,
                    const Eigen::VectorXd* target_offsets = nullptr);

}  // namespace marionette::sot
