// The strict-hierarchy algorithm against closed forms: the pseudo-inverse of one task, the
// classic projector recursion (Nicolin 2022 eq. 3.5–3.6, computed independently with SVD
// pseudo-inverses) for equality stacks, clamping for separable bounded problems, and hand-solved
// cascades with inequalities (QP levels). The random-stack comparison with a brute-force
// cascade on TALOS Jacobians lives in tests/python/sot/test_strict_priority.py.
#include <gtest/gtest.h>

#include <Eigen/SVD>

#include "marionette/sot/hierarchy.h"

namespace marionette::sot {
namespace {

HierarchyOptions Exact() {
  HierarchyOptions o;
  o.damping = 0.0;
  o.qp_regularization = 1e-10;
  return o;
}

TaskTerms Equality(const Eigen::MatrixXd& J, const Eigen::VectorXd& b) {
  TaskTerms t(static_cast<int>(J.rows()), static_cast<int>(J.cols()));
  t.jacobian = J;
  t.lower = t.upper = b;
  return t;
}

TaskTerms Inequality(const Eigen::MatrixXd& J, const Eigen::VectorXd& lo, const Eigen::VectorXd& hi,
                     std::vector<int> unit_columns = {}) {
  TaskTerms t(static_cast<int>(J.rows()), static_cast<int>(J.cols()));
  t.jacobian = J;
  t.lower = lo;
  t.upper = hi;
  t.inequality = true;
  t.unit_columns = std::move(unit_columns);
  return t;
}

TaskShape ShapeOf(const TaskTerms& t) {
  return {static_cast<int>(t.lower.size()), t.inequality, t.unit_columns};
}

// Solves levels of tasks (one task per level) and returns v.
Eigen::VectorXd Solve(const std::vector<TaskTerms>& levels, HierarchyOptions options = Exact(),
                      HierarchyReport* report = nullptr) {
  std::vector<std::vector<TaskShape>> shapes;
  std::vector<const TaskTerms*> terms;
  for (const TaskTerms& t : levels) {
    shapes.push_back({ShapeOf(t)});
    terms.push_back(&t);
  }
  Hierarchy h(static_cast<int>(levels[0].jacobian.cols()), shapes, options);
  HierarchyWorkspace w(h);
  Eigen::VectorXd v;
  SolveHierarchy(h, terms, &w, &v);
  if (report) *report = w.report();
  return v;
}

Eigen::MatrixXd Pinv(const Eigen::MatrixXd& A) {
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::VectorXd& s = svd.singularValues();
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(A.cols(), A.rows());
  for (int i = 0; i < s.size(); ++i) {
    if (s[i] > 1e-9) S(i, i) = 1.0 / s[i];  // absolute: P ~ 0 leaves only rounding noise
  }
  return svd.matrixV() * S * svd.matrixU().transpose();
}

// Eq. 3.5–3.6: v_{i+1} = v_i + (J P)^+ (b - J v_i), P_{i+1} = P_i - (J P)^+ (J P).
Eigen::VectorXd ProjectorRecursion(const std::vector<TaskTerms>& levels) {
  const int n = static_cast<int>(levels[0].jacobian.cols());
  Eigen::VectorXd v = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd P = Eigen::MatrixXd::Identity(n, n);
  for (const TaskTerms& t : levels) {
    const Eigen::MatrixXd JP = t.jacobian * P;
    const Eigen::MatrixXd JPp = Pinv(JP);
    v += JPp * (t.lower - t.jacobian * v);
    P -= JPp * JP;
  }
  return v;
}

TEST(HierarchyTest, OneTaskGivesThePseudoInverseSolution) {
  std::srand(1);
  const Eigen::MatrixXd J = Eigen::MatrixXd::Random(6, 10);
  const Eigen::VectorXd b = Eigen::VectorXd::Random(6);
  const Eigen::VectorXd v = Solve({Equality(J, b)});
  EXPECT_LT((v - J.completeOrthogonalDecomposition().pseudoInverse() * b).norm(), 1e-12);
}

TEST(HierarchyTest, EqualityStackMatchesTheProjectorRecursion) {
  std::srand(2);
  for (int trial = 0; trial < 20; ++trial) {
    const int n = 12 + trial % 5;
    std::vector<TaskTerms> levels;
    int rows_left = n + 4;  // the last level over-constrains: a least-squares compromise
    for (int l = 0; l < 4; ++l) {
      const int m = l < 3 ? 2 + (trial + l) % 4 : rows_left;
      levels.push_back(Equality(Eigen::MatrixXd::Random(m, n), Eigen::VectorXd::Random(m)));
      rows_left -= m;
      if (rows_left < 1) rows_left = 1;
    }
    const Eigen::VectorXd v = Solve(levels);
    const Eigen::VectorXd ref = ProjectorRecursion(levels);
    for (const TaskTerms& t : levels) {
      EXPECT_LT((t.jacobian * (v - ref)).norm(), 1e-10) << "trial " << trial;
    }
    EXPECT_LT((v - ref).norm(), 1e-10) << "trial " << trial;
  }
}

// A first level whose rows mostly touch few coordinates (a humanoid's feet) is factored on them
// first, and that grouping is reused from one solve to the next while those rows stay zero
// outside them. The second solve, by the same workspace, makes a grouped row touch another
// coordinate: reusing the grouping would then be wrong, the solution must still be the
// projector recursion's.
TEST(HierarchyTest, SparseFirstLevelStaysExactWhenItsPatternChanges) {
  std::srand(4);
  const int n = 20;
  Eigen::MatrixXd J1 = Eigen::MatrixXd::Zero(9, n);
  J1.topLeftCorner(4, 6) = Eigen::MatrixXd::Random(4, 6);  // "left foot": coordinates 0..5
  J1.block(4, 0, 4, 3) = Eigen::MatrixXd::Random(4, 3);    // "right foot": 0..2 and 6..8
  J1.block(4, 6, 4, 3) = Eigen::MatrixXd::Random(4, 3);
  J1.row(8) = Eigen::RowVectorXd::Random(n);  // a dense row ("CoM")
  std::vector<TaskTerms> levels{
      Equality(J1, Eigen::VectorXd::Random(9)),
      Equality(Eigen::MatrixXd::Random(5, n), Eigen::VectorXd::Random(5)),
      Equality(Eigen::MatrixXd::Random(8, n), Eigen::VectorXd::Random(8))};
  std::vector<std::vector<TaskShape>> shapes;
  std::vector<const TaskTerms*> terms;
  for (const TaskTerms& t : levels) {
    shapes.push_back({ShapeOf(t)});
    terms.push_back(&t);
  }
  const Hierarchy h(n, shapes, Exact());
  HierarchyWorkspace w(h);
  for (int solve = 0; solve < 3; ++solve) {
    if (solve == 1) levels[0].jacobian(2, 15) = 0.7;  // a grouped row leaves its coordinates
    if (solve == 2) levels[0].jacobian(2, 15) = 0.0;  // and comes back
    Eigen::VectorXd v;
    SolveHierarchy(h, terms, &w, &v);
    EXPECT_LT((v - ProjectorRecursion(levels)).norm(), 1e-10) << "solve " << solve;
  }
}

TEST(HierarchyTest, ConflictingLevelDoesNotDisturbTheLevelAbove) {
  std::srand(3);
  const int n = 8;
  const Eigen::MatrixXd J1 = Eigen::MatrixXd::Random(3, n);
  // Level 2: two rows inside level 1's row space (fully conflicting) and two free rows.
  Eigen::MatrixXd J2(4, n);
  J2.topRows(2) = Eigen::MatrixXd::Random(2, 3) * J1;
  J2.bottomRows(2) = Eigen::MatrixXd::Random(2, n);
  const std::vector<TaskTerms> levels{Equality(J1, Eigen::VectorXd::Random(3)),
                                      Equality(J2, Eigen::VectorXd::Random(4))};
  HierarchyReport report;
  const Eigen::VectorXd v = Solve(levels, Exact(), &report);
  EXPECT_LT((J1 * v - levels[0].lower).norm(), 1e-12);
  EXPECT_EQ(report.ranks[0], 3);
  EXPECT_EQ(report.ranks[1], 2);  // the dependent rows got no DoF
  EXPECT_LT((v - ProjectorRecursion(levels)).norm(), 1e-10);
}

TEST(HierarchyTest, BoxAtLevelZeroClampsASeparableTask) {
  const int n = 6;
  Eigen::VectorXd lo(n), hi(n), b(n);
  lo << -1, -1, 0, -0.5, -2, -1;
  hi << 1, 1, 0, 0.5, 2, 1;
  b << 0.5, 3, 0.2, -0.7, 1.5, -1;
  std::vector<int> cols{0, 1, 2, 3, 4, 5};
  HierarchyReport report;
  const Eigen::VectorXd v = Solve({Inequality(Eigen::MatrixXd::Identity(n, n), lo, hi, cols),
                                   Equality(Eigen::MatrixXd::Identity(n, n), b)},
                                  Exact(), &report);
  EXPECT_LT((v - b.cwiseMax(lo).cwiseMin(hi)).norm(), 1e-9);
  EXPECT_TRUE(report.qp_levels[1]);
  EXPECT_EQ(report.qp_failures, 0);
}

TEST(HierarchyTest, InequalityBelowAnEqualityIsSolvedAsACascade) {
  // Level 1: v0 + v1 = 1. Level 2: v0 >= 2. Level 3: v = 0 (least norm). Closed form: S_2 is
  // the half-line v0 >= 2 of the line, its point closest to 0 is (2, -1).
  Eigen::MatrixXd J1(1, 2);
  J1 << 1, 1;
  Eigen::MatrixXd J2(1, 2);
  J2 << 1, 0;
  const std::vector<TaskTerms> levels{
      Equality(J1, Eigen::VectorXd::Ones(1)),
      Inequality(J2, Eigen::VectorXd::Constant(1, 2.0),
                 Eigen::VectorXd::Constant(1, std::numeric_limits<double>::infinity())),
      Equality(Eigen::MatrixXd::Identity(2, 2), Eigen::VectorXd::Zero(2))};
  HierarchyReport report;
  const Eigen::VectorXd v = Solve(levels, Exact(), &report);
  EXPECT_LT((v - Eigen::Vector2d(2, -1)).norm(), 1e-9) << v.transpose();
  EXPECT_TRUE(report.qp_levels[1]);
}

TEST(HierarchyTest, InfeasibleInequalityKeepsItsOptimalSlackForLowerLevels) {
  // Level 1: v0 = 0. Level 2: v0 + v1 >= 1 and v0 - v1 >= 1, i.e. v1 >= 1 and v1 <= -1: the
  // least violation (1 - v1)+² + (1 + v1)+² is at v1 = 0, both rows short by 1. A lower level
  // asking v1 = 5 must not change that.
  Eigen::MatrixXd J1(1, 2);
  J1 << 1, 0;
  Eigen::MatrixXd C(2, 2);
  C << 1, 1, 1, -1;
  const double inf = std::numeric_limits<double>::infinity();
  const std::vector<TaskTerms> levels{
      Equality(J1, Eigen::VectorXd::Zero(1)),
      Inequality(C, Eigen::VectorXd::Ones(2), Eigen::VectorXd::Constant(2, inf)),
      Equality((Eigen::MatrixXd(1, 2) << 0, 1).finished(), Eigen::VectorXd::Constant(1, 5.0))};
  const Eigen::VectorXd v = Solve(levels);
  EXPECT_LT((v - Eigen::Vector2d(0, 0)).norm(), 1e-8) << v.transpose();
}

TEST(HierarchyTest, DampingBoundsTheVelocityNearASingularity) {
  Eigen::MatrixXd J(2, 2);
  J << 1, 0, 0, 1e-6;  // nearly singular second row
  const Eigen::VectorXd b = Eigen::Vector2d(0.1, 0.1);
  const Eigen::VectorXd exact = Solve({Equality(J, b)});
  EXPECT_NEAR(exact[1], 1e5, 1.0);
  HierarchyOptions damped;
  damped.damping = 0.02;
  damped.damping_threshold = 0.02;
  HierarchyReport report;
  const Eigen::VectorXd v = Solve({Equality(J, b)}, damped, &report);
  EXPECT_LT(v.cwiseAbs().maxCoeff(), 0.1 / (2 * 0.02) + 1e-9);  // |σ b / (σ² + μ²)| <= b / 2μ
  EXPECT_GT(report.dampings[0], 0.019);
  // Far from singular, damping changes nothing.
  const Eigen::MatrixXd Jw = Eigen::Matrix2d::Identity();
  EXPECT_LT((Solve({Equality(Jw, b)}, damped) - b).norm(), 1e-15);
}

TEST(HierarchyTest, RejectsMismatchedTasks) {
  Hierarchy h(3, {{TaskShape{2, false, {}}}});
  HierarchyWorkspace w(h);
  Eigen::VectorXd v;
  const TaskTerms wrong = Equality(Eigen::MatrixXd::Ones(3, 3), Eigen::VectorXd::Ones(3));
  EXPECT_THROW(SolveHierarchy(h, {&wrong}, &w, &v), SotError);
  EXPECT_THROW(SolveHierarchy(h, {}, &w, &v), SotError);
  EXPECT_THROW(Hierarchy(0, {}), SotError);
  EXPECT_THROW(Hierarchy(3, {{TaskShape{0, false, {}}}}), SotError);
}

}  // namespace
}  // namespace marionette::sot
