// Planning inside one leaf of a transition (the per-transition planner of HPP's
// TransitionPlanner / InStatePlanner): OMPL's RRT-Connect over the leaf's free variables, with
// the leaf's explicit constraints substituted at every configuration and every motion checked
// by the certified PathValidator.
// A leaf whose constraints are all explicit (locked joints, objects attached to a joint) is the
// space of its free 1-dof joints: a straight motion there is what
// marionette.planning.path.ConstrainedPath interpolates (free variables on a line, the rest
// substituted), so the returned polyline is a chain of the planner's constrained paths.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "marionette/planning/path_validator.h"
#include "marionette/planning/projector.h"

namespace marionette::planning {

/// One query.  free_idx_q: q indices of the free 1-dof joints (the planning space);
/// lower/upper: their bounds (same order).  Every other entry of q is copied from q_start,
/// then sub substitutes the explicit constraints.
struct LeafQuery {
  Eigen::VectorXd q_start, q_goal;  // (nq) both satisfy the leaf's constraints
  std::vector<int> free_idx_q;
  Eigen::VectorXd lower, upper;  // (free)
  Substitution sub;
};

struct LeafPlannerOptions {
  int max_iterations = 200;  // RRT-Connect iterations (each: one sample, two tree extensions)
  double max_time_s = 1.0;   // wall-clock guard on top of the iterations
  double range = 0.0;        // longest tree edge [rad in the free space]; 0: OMPL's default
  std::uint32_t seed = 0;    // the sampler's seed: same query and seed -> same path
};

struct LeafPlanResult {
  bool solved = false;
  Eigen::MatrixXd waypoints;  // (k x nq) from q_start to q_goal, explicit constraints substituted
  int iterations = 0;
  std::int64_t queries = 0;  // collision pair queries made
};

/// RRT-Connect in the leaf (see the file comment).  The validator is borrowed (one per thread);
/// motion = the transition's pair bounds (rigid, skipped grasp contacts).
/// Throws std::invalid_argument on sizes that do not match the validator's model.
LeafPlanResult PlanInLeaf(PathValidator* validator, const PairMotion& motion,
                          const LeafQuery& query, const LeafPlannerOptions& options);

/// A leaf with implicit constraints (a humanoid's feet and centre of mass): its configurations
/// are the projector's solutions with the right-hand sides rhs / surface pairs.  Samples draw
/// the q entries sample_idx_q uniformly in [lower, upper] (the others, quaternions included,
/// from q_start) and are projected; the trees grow by steps of at most `step` (the metric of
/// pinocchio::difference), each new node projected, no farther than 2 step from its parent,
/// and each segment certified -- exactly the polyline marionette.planning.path.ConstrainedPath
/// builds by progressive projection, so the result is one such path.
struct ConstrainedLeafQuery {
  Eigen::VectorXd q_start, q_goal;  // (nq) both on the leaf
  Eigen::VectorXd rhs;              // the projector's packed right-hand sides
  std::vector<int> pairs;           // its surface pair per placement
  std::vector<int> sample_idx_q;
  Eigen::VectorXd lower, upper;  // (sample_idx_q)
  Substitution sub;              // the explicit constraints, for the validator
  double step = 0.1;
  double error_threshold = 1e-4;
  int projection_iterations = 40;
};

/// Bidirectional RRT-Connect on the leaf (CBiRRT's projection of every new node).  The
/// validator and projector are borrowed (one per thread).  Throws std::invalid_argument on
/// sizes that do not match the models.
LeafPlanResult PlanInConstrainedLeaf(PathValidator* validator, Projector* projector,
                                     const PairMotion& motion, const ConstrainedLeafQuery& query,
                                     const LeafPlannerOptions& options);

}  // namespace marionette::planning
