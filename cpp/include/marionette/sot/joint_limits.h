#pragma once
/// Joint position and velocity limits as an inequality task (the solver keeps every level
/// inside them when the task is at level 0):
///   e = q_j (posture feature against the neutral configuration), J = unit rows,
///   λ (q_min - q) <= v_j <= λ (q_max - q)   and   -v_max <= v_j <= v_max.
/// λ = position_gain [1/s]; λ dt = 0.5 at 1 kHz (500 /s) lets a joint cover half of its distance
/// to the limit per tick, as pink's ConfigurationLimit(gain=0.5) does, and never crosses it
/// with explicit Euler integration (λ dt <= 1).

#include <string>
#include <vector>

#include "marionette/graph/graph.h"
#include "marionette/sot/feature_posture.h"
#include "marionette/sot/task.h"

namespace marionette::sot {

struct JointLimitsOptions {
  double position_gain = 500.0;  ///< λ [1/s]
  double velocity_scale = 1.0;   ///< fraction of the URDF velocity limits allowed
  double margin = 0.0;           ///< [rad or m] kept away from each position limit
};

/// 1-DoF joints with finite position limits (a humanoid's and an arm's joints; not continuous
/// wheels).
std::vector<std::string> LimitedJoints(const pinocchio::Model& model);

/// The bounds of the joint-limit task over `feature` (a posture feature whose reference is the
/// neutral configuration). Throws SotError on bad options or limits narrower than 2 margins.
TaskBounds JointLimitBounds(const pinocchio::Model& model, const FeaturePosture& feature,
                            const JointLimitsOptions& options);

/// Adds the feature "<name>_feature" (plugged to `kinematics`) and the inequality task `name`
/// (gain = options.position_gain) to `builder`; returns the task.
Task& AddJointLimits(graph::GraphBuilder& builder, const std::string& name, ModelPtr model,
                     graph::OutputSignal<Kinematics>& kinematics,
                     const JointLimitsOptions& options = {});

/// Velocity components held at zero: degrees of freedom the model has but no device executes
/// (a planar base: the simulated wheels do not exist, and a differential drive could not
/// follow a sideways base velocity anyway). e = 0, J = unit rows on `v_indices`; as an inequality
/// task with rates bounded to [0, 0] at level 0 (HeldVelocityBounds) it is a hard box: no level may
/// reach a task through these velocities, which would integrate into a command nobody executes.
class FeatureHeldVelocities final : public Feature {
 public:
  /// Throws SotError on an empty list, an index outside [0, nv) or a repeated index.
  FeatureHeldVelocities(std::string name, ModelPtr model, const std::vector<int>& v_indices);
  const char* type_name() const override { return "FeatureHeldVelocities"; }

 protected:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;
};

/// Rates bounded to [0, 0], error unbounded: the bounds that make FeatureHeldVelocities a hold.
TaskBounds HeldVelocityBounds(const FeatureHeldVelocities& feature);

}  // namespace marionette::sot
