#include "marionette/planning/leaf_planner.h"

#include <chrono>
#include <memory>
#include <stdexcept>
#include <string>

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

  bool IsValid(const ob::State* s) {
    ++checks_;
    return validator_->IsValid(Configuration(s), motion_.skip);
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

}  // namespace marionette::planning
