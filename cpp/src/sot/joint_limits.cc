#include "marionette/sot/joint_limits.h"

#include <cmath>

#include <pinocchio/algorithm/joint-configuration.hpp>

namespace marionette::sot {

namespace {
constexpr double kNoLimit = 1e10;  // URDF parsers store "no limit" as ±max double
}

std::vector<std::string> LimitedJoints(const pinocchio::Model& model) {
  std::vector<std::string> names;
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
    if (model.nvs[j] != 1 || model.nqs[j] != 1) continue;
    const int iq = model.idx_qs[j];
    if (model.lowerPositionLimit[iq] > -kNoLimit && model.upperPositionLimit[iq] < kNoLimit) {
      names.push_back(model.names[j]);
    }
  }
  return names;
}

TaskBounds JointLimitBounds(const pinocchio::Model& model, const FeaturePosture& feature,
                            const JointLimitsOptions& options) {
  const std::string who = "joint limits '" + feature.name() + "'";
  if (!(options.position_gain > 0.0) || !(options.velocity_scale > 0.0) || options.margin < 0.0) {
    throw SotError(who + ": needs position_gain > 0, velocity_scale > 0, margin >= 0");
  }
  const Eigen::VectorXd q0 = pinocchio::neutral(model);
  const int k = feature.dimension();
  TaskBounds b;
  b.error_lower.resize(k);
  b.error_upper.resize(k);
  b.rate_lower.resize(k);
  b.rate_upper.resize(k);
  for (int i = 0; i < k; ++i) {
    const int iq = feature.q_indices()[i], iv = feature.v_indices()[i];
    b.error_lower[i] = model.lowerPositionLimit[iq] + options.margin - q0[iq];
    b.error_upper[i] = model.upperPositionLimit[iq] - options.margin - q0[iq];
    if (b.error_lower[i] > b.error_upper[i]) {
      throw SotError(who + ": joint '" + feature.joint_names()[i] +
                     "' range is narrower than 2 margins");
    }
    // URDF velocity limits are symmetric; Pinocchio 4 stores +max in both lower and upper.
    const double limit = std::abs(model.upperVelocityLimit[iv]);
    const double v_max =
        limit < kNoLimit ? options.velocity_scale * limit : std::numeric_limits<double>::infinity();
    b.rate_lower[i] = -v_max;
    b.rate_upper[i] = v_max;
  }
  return b;
}

Task& AddJointLimits(graph::GraphBuilder& builder, const std::string& name, ModelPtr model,
                     graph::OutputSignal<Kinematics>& kinematics,
                     const JointLimitsOptions& options) {
  auto& feature = builder.Add<FeaturePosture>(name + "_feature", model, LimitedJoints(*model));
  builder.Connect(kinematics, feature.kinematics_input());
  return builder.Add<Task>(name, feature, Gain::Constant(options.position_gain),
                           JointLimitBounds(*model, feature, options));
}

FeatureHeldVelocities::FeatureHeldVelocities(std::string name, ModelPtr model,
                                             const std::vector<int>& v_indices)
    : Feature(name, model, static_cast<int>(v_indices.size()), {}) {
  if (v_indices.empty()) throw SotError(who() + ": no velocity to hold");
  std::vector<bool> seen(model_->nv, false);
  for (int i : v_indices) {
    if (i < 0 || i >= model_->nv) {
      throw SotError(who() + ": velocity index " + std::to_string(i) + " outside [0, " +
                     std::to_string(model_->nv) + ")");
    }
    if (seen[i]) throw SotError(who() + ": velocity index " + std::to_string(i) + " twice");
    seen[i] = true;
  }
  SetUnitJacobian(v_indices);
  DeclareTermsOutput({});
}

void FeatureHeldVelocities::ComputeFull(const graph::Tick&, const Kinematics&,
                                        FeatureTerms* full) const {
  full->error.setZero();
  full->drift.setZero();
}

TaskBounds HeldVelocityBounds(const FeatureHeldVelocities& feature) {
  TaskBounds b;
  b.rate_lower = Eigen::VectorXd::Zero(feature.dimension());
  b.rate_upper = Eigen::VectorXd::Zero(feature.dimension());
  return b;
}

}  // namespace marionette::sot
