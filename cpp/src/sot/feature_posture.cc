#include "marionette/sot/feature_posture.h"

#include <cmath>

#include <pinocchio/algorithm/joint-configuration.hpp>

namespace marionette::sot {

std::vector<std::string> OneDofJoints(const pinocchio::Model& model) {
  std::vector<std::string> names;
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
    if (model.nvs[j] == 1) names.push_back(model.names[j]);
  }
  return names;
}

FeaturePosture::Joints FeaturePosture::Resolve(const ModelPtr& model,
                                               const std::vector<std::string>& joints,
                                               const std::string& who) {
  if (!model) throw SotError(who + ": null model");
  Joints out;
  out.names = joints.empty() ? OneDofJoints(*model) : joints;
  if (out.names.empty()) throw SotError(who + ": the model has no 1-DoF joint");
  for (const std::string& name : out.names) {
    if (!model->existJointName(name)) {
      throw SotError(who + ": unknown joint '" + name + "' in model '" + model->name + "'");
    }
    const pinocchio::JointIndex j = model->getJointId(name);
    if (model->nvs[j] != 1) {
      throw SotError(who + ": joint '" + name + "' has " + std::to_string(model->nvs[j]) +
                     " DoF; a posture holds 1-DoF joints (use an se3 task for the base)");
    }
    out.q.push_back(model->idx_qs[j]);
    out.v.push_back(model->idx_vs[j]);
    out.continuous.push_back(model->nqs[j] == 2);
  }
  return out;
}

FeaturePosture::FeaturePosture(std::string name, ModelPtr model,
                               const std::vector<std::string>& joints)
    : Feature(
          name, model,
          static_cast<int>(Resolve(model, joints, "FeaturePosture '" + name + "'").names.size()),
          {}),
      joints_(Resolve(model_, joints, who())) {
  joint_names_ = joints_.names;
  q_indices_.clear();
  for (size_t i = 0; i < joints_.q.size(); ++i) {
    q_indices_.push_back(joints_.q[i]);
    if (joints_.continuous[i]) q_indices_.push_back(joints_.q[i] + 1);
  }
  v_indices_ = joints_.v;
  SetUnitJacobian(joints_.v);
  reference_ = &DeclareParameter<Eigen::VectorXd>("reference", pinocchio::neutral(*model_));
  reference_velocity_ =
      &DeclareParameter<Eigen::VectorXd>("reference_velocity", Eigen::VectorXd::Zero(model_->nv));
  DeclareTermsOutput({reference_, reference_velocity_});
}

void FeaturePosture::ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                                 FeatureTerms* full) const {
  const Eigen::VectorXd& q = kinematics.q();
  const Eigen::VectorXd& q_ref = reference_->Eval(t);
  const Eigen::VectorXd& v_ref = reference_velocity_->Eval(t);
  for (size_t i = 0; i < joints_.q.size(); ++i) {
    const int iq = joints_.q[i];
    if (joints_.continuous[i]) {
      // SO(2) stored as (cos θ, sin θ): θ - θ* = atan2(sin(θ - θ*), cos(θ - θ*)).
      const double c = q[iq], s = q[iq + 1], cr = q_ref[iq], sr = q_ref[iq + 1];
      full->error[i] = std::atan2(cr * s - sr * c, cr * c + sr * s);
    } else {
      full->error[i] = q[iq] - q_ref[iq];
    }
    full->drift[i] = -v_ref[joints_.v[i]];
  }
}

}  // namespace marionette::sot
