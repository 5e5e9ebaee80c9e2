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

/// 1-DoF joints with finite position limits (all TALOS, UR10 joints; not continuous wheels).
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

}  // namespace marionette::sot
