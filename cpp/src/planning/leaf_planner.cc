#include "marionette/planning/leaf_planner.h"

#include <algorithm>
#include <chrono>
#include <limits>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>

#include <pinocchio/algorithm/joint-configuration.hpp>

#include <ompl/base/MotionValidator.h>
#include <ompl/base/SpaceInformation.h>
#include <ompl/base/StateValidityChecker.h>
#include <ompl/base/spaces/RealVectorStateSpace.h>
#include <ompl/datastructures/NearestNeighborsLinear.h>
#include <ompl/geometric/PathGeometric.h>
#include <ompl/geometric/planners/rrt/RRTConnect.h>
#include <ompl/util/Console.h>

namespace marionette::planning {
namespace {

namespace ob = ompl::base;
namespace og = ompl::geometric;

// The uniform sampler of the free space with its own seed (OMPL's default one draws its seed
// from a process-wide generator: the same query would give another path on every call).
class SeededSampler : public ob::RealVectorStateSampler {
 public:
  SeededSampler(const ob::StateSpace* space, std::uint32_t seed) : RealVectorStateSampler(space) {
    rng_.setLocalSeed(seed);
  }
};

// Maps states of the free space to configurations and checks them with the validator.
class Leaf {
 public:
  Leaf(PathValidator* validator, const PairMotion& motion, const LeafQuery& query)
      : validator_(validator), motion_(motion), query_(query), q_(query.q_start) {}

  // q (nq) of a state: free joints from the state, the rest from q_start, then substituted.
  const Eigen::VectorXd& Configuration(const ob::State* s) {
    const auto* x = s->as<ob::RealVectorStateSpace::StateType>();
    q_ = query_.q_start;
    for (size_t k = 0; k < query_.free_idx_q.size(); ++k) q_[query_.free_idx_q[k]] = (*x)[k];
    validator_->Substitute(query_.sub, &q_);
    return q_;
  }

  // The query's own ends may be closer than the clearance (a given start or goal placed close);
  // every configuration the planner adds keeps it, so no path from it is excused.
  bool IsValid(const ob::State* s) {
    ++checks_;
    const Eigen::VectorXd& q = Configuration(s);
    if (IsQueryEnd(q)) return validator_->IsValid(q, motion_.skip);
    return validator_->IsClear(q, motion_);
  }

  // All-or-nothing certified validation of the straight motion a -> b (the polyline's segment).
  bool CheckMotion(const ob::State* a, const ob::State* b, double length) {
    Polyline line;
    line.points.resize(2, validator_->model().nq);
    line.points.row(0) = Configuration(a).transpose();
    line.points.row(1) = Configuration(b).transpose();
    line.cum = Eigen::Vector2d(0.0, length);
    const ValidationResult r = validator_->Validate(line, query_.sub, motion_, /*probes=*/true);
    queries_ += r.queries;
    return r.valid;
  }

  std::int64_t queries() const { return queries_; }

 private:
  bool IsQueryEnd(const Eigen::VectorXd& q) const {
    auto same = [&](const Eigen::VectorXd& end) {
      for (const int i : query_.free_idx_q)
        if (q[i] != end[i]) return false;
      return true;
    };
    return same(query_.q_start) || same(query_.q_goal);
  }

  PathValidator* validator_;
  const PairMotion& motion_;
  const LeafQuery& query_;
  Eigen::VectorXd q_;
  std::int64_t checks_ = 0, queries_ = 0;
};

class CertifiedMotionValidator : public ob::MotionValidator {
 public:
  CertifiedMotionValidator(const ob::SpaceInformationPtr& si, Leaf* leaf)
      : MotionValidator(si), leaf_(leaf) {}

  bool checkMotion(const ob::State* s1, const ob::State* s2) const override {
    if (!si_->isValid(s2)) {
      ++invalid_;
      return false;
    }
    const bool ok = leaf_->CheckMotion(s1, s2, si_->distance(s1, s2));
    ok ? ++valid_ : ++invalid_;
    return ok;
  }

  // RRT-Connect only asks all-or-nothing questions; this form keeps no valid prefix.
  bool checkMotion(const ob::State* s1, const ob::State* s2,
                   std::pair<ob::State*, double>& last_valid) const override {
    const bool ok = checkMotion(s1, s2);
    if (!ok) {
      if (last_valid.first != nullptr) si_->copyState(last_valid.first, s1);
      last_valid.second = 0.0;
    }
    return ok;
  }

 private:
  Leaf* leaf_;
};

}  // namespace

LeafPlanResult PlanInLeaf(PathValidator* validator, const PairMotion& motion,
                          const LeafQuery& query, const LeafPlannerOptions& options) {
  const int nq = validator->model().nq;
  const auto n = static_cast<unsigned>(query.free_idx_q.size());
  if (query.q_start.size() != nq || query.q_goal.size() != nq)
    throw std::invalid_argument(
        "leaf planner: q_start and q_goal must have nq = " + std::to_string(nq) + " entries");
  if (n == 0 || query.lower.size() != n || query.upper.size() != n)
    throw std::invalid_argument(
        "leaf planner: free_idx_q, lower and upper must be non-empty and "
        "of one size");
  for (int i : query.free_idx_q)
    if (i < 0 || i >= nq) throw std::invalid_argument("leaf planner: free index out of q");
  for (unsigned k = 0; k < n; ++k)
    if (!(query.lower[k] < query.upper[k]))
      throw std::invalid_argument("leaf planner: lower bound not below upper bound");
  ompl::msg::setLogLevel(ompl::msg::LOG_NONE);

  auto space = std::make_shared<ob::RealVectorStateSpace>(n);
  ob::RealVectorBounds bounds(n);
  for (unsigned k = 0; k < n; ++k) {
    bounds.setLow(k, query.lower[k]);
    bounds.setHigh(k, query.upper[k]);
  }
  space->setBounds(bounds);
  const std::uint32_t seed = options.seed;
  space->setStateSamplerAllocator(
      [seed](const ob::StateSpace* s) { return std::make_shared<SeededSampler>(s, seed); });
  auto si = std::make_shared<ob::SpaceInformation>(space);
  Leaf leaf(validator, motion, query);
  si->setStateValidityChecker([&leaf](const ob::State* s) { return leaf.IsValid(s); });
  si->setMotionValidator(std::make_shared<CertifiedMotionValidator>(si, &leaf));
  si->setup();

  ob::ScopedState<ob::RealVectorStateSpace> start(space), goal(space);
  for (unsigned k = 0; k < n; ++k) {
    start[k] = query.q_start[query.free_idx_q[k]];
    goal[k] = query.q_goal[query.free_idx_q[k]];
  }
  auto pdef = std::make_shared<ob::ProblemDefinition>(si);
  pdef->setStartAndGoalStates(start, goal);
  auto planner = std::make_shared<og::RRTConnect>(si);
  planner->setNearestNeighbors<ompl::NearestNeighborsLinear>();
  if (options.range > 0.0) planner->setRange(options.range);
  planner->setProblemDefinition(pdef);
  planner->setup();

  LeafPlanResult out;
  int iterations = 0;
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(options.max_time_s);
  // RRT-Connect evaluates the condition once per iteration: a count keeps runs reproducible.
  const ob::PlannerTerminationCondition ptc([&iterations, &options, deadline] {
    return ++iterations > options.max_iterations || std::chrono::steady_clock::now() > deadline;
  });
  const ob::PlannerStatus status = planner->solve(ptc);
  out.iterations = std::min(iterations, options.max_iterations);
  out.queries = leaf.queries();
  if (status != ob::PlannerStatus::EXACT_SOLUTION) return out;
  const auto& path = *pdef->getSolutionPath()->as<og::PathGeometric>();
  const std::size_t k = path.getStateCount();
  out.waypoints.resize(static_cast<Eigen::Index>(k), nq);
  for (std::size_t i = 0; i < k; ++i)
    out.waypoints.row(static_cast<Eigen::Index>(i)) = leaf.Configuration(path.getState(i));
  // The ends are the caller's configurations exactly (consecutive paths join exactly).
  out.waypoints.row(0) = query.q_start.transpose();
  out.waypoints.row(static_cast<Eigen::Index>(k) - 1) = query.q_goal.transpose();
  out.solved = true;
  return out;
}

namespace {

// One tree of the constrained RRT-Connect: nodes (nq) and their parents (-1 at the root).
struct Tree {
  std::vector<Eigen::VectorXd> q;
  std::vector<int> parent;

  int Nearest(const Eigen::VectorXd& x) const {
    int best = 0;
    double best_d = std::numeric_limits<double>::infinity();
    for (size_t i = 0; i < q.size(); ++i) {
      const double d = (q[i] - x).squaredNorm();
      if (d < best_d) {
        best_d = d;
        best = static_cast<int>(i);
      }
    }
    return best;
  }

  // Configurations from the root to node i.
  std::vector<Eigen::VectorXd> Branch(int i) const {
    std::vector<Eigen::VectorXd> out;
    for (; i >= 0; i = parent[i]) out.push_back(q[i]);
    std::reverse(out.begin(), out.end());
    return out;
  }
};

class ConstrainedLeaf {
 public:
  ConstrainedLeaf(PathValidator* validator, Projector* projector, const PairMotion& motion,
                  const ConstrainedLeafQuery& query)
      : validator_(validator),
        projector_(projector),
        motion_(motion),
        query_(query),
        dv_(validator->model().nv) {}

  // Projects q in place onto the leaf; false when the projection fails.
  bool Project(Eigen::VectorXd* q) {
    std::vector<int> pairs = query_.pairs;
    const ProjectionOutcome r = projector_->Project(*q, query_.rhs, &pairs, query_.error_threshold,
                                                    query_.projection_iterations);
    return r.status == ProjectionStatus::kSuccess;
  }

  // Certified, all or nothing, validation of the segment a -> b.
  bool Segment(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
    Polyline line;
    line.points.resize(2, a.size());
    line.points.row(0) = a.transpose();
    line.points.row(1) = b.transpose();
    pinocchio::difference(validator_->model(), a, b, dv_);
    line.cum = Eigen::Vector2d(0.0, dv_.norm());
    const ValidationResult r = validator_->Validate(line, query_.sub, motion_, /*probes=*/true);
    queries_ += r.queries;
    return r.valid;
  }

  double Distance(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
    pinocchio::difference(validator_->model(), a, b, dv_);
    return dv_.norm();
  }

  // One step of at most `step` from tree node i toward target; the new node's index, or -1
  // (projection failed, jumped, or the segment collides).  reached: the target itself added.
  int Extend(Tree* tree, int i, const Eigen::VectorXd& target, bool* reached) {
    const Eigen::VectorXd& from = tree->q[i];
    const double d = Distance(from, target);
    *reached = d <= query_.step;
    Eigen::VectorXd q(from.size());
    if (*reached) {
      q = target;  // on the leaf already (a node of the other tree)
    } else {
      pinocchio::interpolate(validator_->model(), from, target, query_.step / d, q);
      if (!Project(&q)) return -1;
      if (Distance(from, q) > 2.0 * query_.step) return -1;  // continuity (Progressive)
    }
    // A node keeps the clearance (the query's ends may not: a given start or goal placed close).
    if (q != query_.q_start && q != query_.q_goal && !validator_->IsClear(q, motion_)) return -1;
    if (!Segment(from, q)) return -1;
    tree->q.push_back(q);
    tree->parent.push_back(i);
    return static_cast<int>(tree->q.size()) - 1;
  }

  // Extends toward target until reached (-2), blocked (-1) or the target is a sample that was
  // reached; returns the last node added.
  int Connect(Tree* tree, const Eigen::VectorXd& target, bool* reached, int max_steps) {
    int i = tree->Nearest(target), last = -1;
    *reached = false;
    for (int k = 0; k < max_steps && !*reached; ++k) {
      const int n = Extend(tree, i, target, reached);
      if (n < 0) break;
      i = last = n;
    }
    return last;
  }

  std::int64_t queries() const { return queries_; }

 private:
  PathValidator* validator_;
  Projector* projector_;
  const PairMotion& motion_;
  const ConstrainedLeafQuery& query_;
  Eigen::VectorXd dv_;
  std::int64_t queries_ = 0;
};

}  // namespace

LeafPlanResult PlanInConstrainedLeaf(PathValidator* validator, Projector* projector,
                                     const PairMotion& motion, const ConstrainedLeafQuery& query,
                                     const LeafPlannerOptions& options) {
  const int nq = validator->model().nq;
  if (projector->model().nq != nq)
    throw std::invalid_argument("constrained leaf planner: projector and validator differ in nq");
  if (query.q_start.size() != nq || query.q_goal.size() != nq)
    throw std::invalid_argument("constrained leaf planner: q_start and q_goal must have nq = " +
                                std::to_string(nq) + " entries");
  const size_t n = query.sample_idx_q.size();
  if (query.lower.size() != static_cast<Eigen::Index>(n) ||
      query.upper.size() != static_cast<Eigen::Index>(n))
    throw std::invalid_argument("constrained leaf planner: lower / upper sized as sample_idx_q");
  for (int i : query.sample_idx_q)
    if (i < 0 || i >= nq) throw std::invalid_argument("constrained leaf planner: index out of q");
  if (!(query.step > 0.0))
    throw std::invalid_argument("constrained leaf planner: step must be > 0");
  if (query.rhs.size() != projector->rhs_size())
    throw std::invalid_argument("constrained leaf planner: rhs has " +
                                std::to_string(query.rhs.size()) + " entries, expected " +
                                std::to_string(projector->rhs_size()));

  ConstrainedLeaf leaf(validator, projector, motion, query);
  Tree a, b;
  a.q.push_back(query.q_start);
  a.parent.push_back(-1);
  b.q.push_back(query.q_goal);
  b.parent.push_back(-1);
  std::mt19937 rng(options.seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(options.max_time_s);
  // A connect attempt walks at most as far as the bounds' diagonal allows.
  const int max_steps = 1000;
  LeafPlanResult out;
  Tree* ta = &a;
  Tree* tb = &b;
  Eigen::VectorXd sample(nq);
  for (int it = 0; it < options.max_iterations; ++it) {
    out.iterations = it + 1;
    if (std::chrono::steady_clock::now() > deadline) break;
    // First try: the two roots directly; then samples.
    bool reached = false;
    int na;
    if (it == 0) {
      sample = tb->q[0];
    } else {
      sample = query.q_start;
      for (size_t k = 0; k < n; ++k)
        sample[query.sample_idx_q[k]] =
            query.lower[k] + unit(rng) * (query.upper[k] - query.lower[k]);
      if (!leaf.Project(&sample)) {
        std::swap(ta, tb);
        continue;
      }
    }
    na = leaf.Connect(ta, sample, &reached, it == 0 ? max_steps : 1);
    if (na >= 0) {
      const int nb = leaf.Connect(tb, ta->q[na], &reached, max_steps);
      if (reached && nb >= 0) {
        std::vector<Eigen::VectorXd> from_a = ta->Branch(na), from_b = tb->Branch(nb);
        // from_b ends at the node equal to ta->q[na]: drop it, then walk back to b's root.
        from_b.pop_back();
        std::reverse(from_b.begin(), from_b.end());
        from_a.insert(from_a.end(), from_b.begin(), from_b.end());
        if (ta != &a) std::reverse(from_a.begin(), from_a.end());
        out.waypoints.resize(static_cast<Eigen::Index>(from_a.size()), nq);
        for (size_t i = 0; i < from_a.size(); ++i)
          out.waypoints.row(static_cast<Eigen::Index>(i)) = from_a[i].transpose();
        out.waypoints.row(0) = query.q_start.transpose();
        out.waypoints.row(out.waypoints.rows() - 1) = query.q_goal.transpose();
        out.solved = true;
        out.queries = leaf.queries();
        return out;
      }
    }
    std::swap(ta, tb);
  }
  out.queries = leaf.queries();
  return out;
}

}  // namespace marionette::planning
