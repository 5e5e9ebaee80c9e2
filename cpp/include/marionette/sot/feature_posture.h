#pragma once
/// Posture of a subset of 1-DoF joints (Nicolin 2022 §3.2.4.1, e = q - q_des):
///   e_i = q_{j_i} ⊖ q*_{j_i}  (difference on the joint's manifold: angle for continuous joints)
///   J   = unit rows e_{v(j_i)}^T (constant),   ∂e/∂t = -v*_{v(j_i)}
/// @entity  inputs: kinematics, reference (nq, full configuration, default neutral),
///          reference_velocity (nv, default 0)   outputs: terms, error, jacobian

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeaturePosture final : public Feature {
 public:
  /// `joints`: joint names; empty = every 1-DoF joint (all actuated joints). Throws SotError on
  /// an unknown joint or a joint with more than one DoF (the base: use an SE3 task).
  FeaturePosture(std::string name, ModelPtr model, const std::vector<std::string>& joints = {});
  const char* type_name() const override { return "FeaturePosture"; }
  graph::InputSignal<Eigen::VectorXd>& reference_input() { return *reference_; }
  graph::InputSignal<Eigen::VectorXd>& reference_velocity_input() { return *reference_velocity_; }
  const std::vector<std::string>& joint_names() const { return joint_names_; }
  /// Configuration indices (q) of the joints, in order; 2 entries (cos, sin) for continuous ones.
  const std::vector<int>& q_indices() const { return q_indices_; }
  /// Tangent indices (v) of the joints, in order.
  const std::vector<int>& v_indices() const { return v_indices_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  struct Joints {
    std::vector<std::string> names;
    std::vector<int> q, v;         // first configuration index and tangent index of each joint
    std::vector<bool> continuous;  // nq = 2 (cos, sin) joints
  };
  static Joints Resolve(const ModelPtr& model, const std::vector<std::string>& joints,
                        const std::string& who);

  Joints joints_;
  std::vector<std::string> joint_names_;
  std::vector<int> q_indices_, v_indices_;
  graph::InputSignal<Eigen::VectorXd>* reference_{};
  graph::InputSignal<Eigen::VectorXd>* reference_velocity_{};
};

/// Every 1-DoF joint of `model` (the actuated joints of a humanoid, an arm, a mobile base's
/// arm...).
std::vector<std::string> OneDofJoints(const pinocchio::Model& model);

}  // namespace marionette::sot
