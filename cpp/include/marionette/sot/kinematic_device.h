#pragma once
/// KinematicDevice: a perfect velocity-controlled robot for fast tests and benchmarks. The
/// command is integrated on the configuration manifold (free-flyer quaternion included):
///   q_{t+1} = q_t ⊕ v_t dt      (Pinocchio integrate),     v_applied_{t+1} = v_t
/// @entity  inputs: command (nv)   states: configuration (nq), velocity (nv, the command applied
///          during the previous tick: the v(τ⁻) a newly swapped-in Solver blends from)

#include <Eigen/Core>
#include <string>

#include "marionette/graph/entity.h"
#include "marionette/sot/kinematics.h"

namespace marionette::sot {

class KinematicDevice final : public graph::Entity {
 public:
  /// Throws SotError when q0 has the wrong size, is not finite or has a non-unit quaternion.
  KinematicDevice(std::string name, ModelPtr model, const Eigen::VectorXd& q0);
  const char* type_name() const override { return "KinematicDevice"; }
  graph::InputSignal<Eigen::VectorXd>& command_input() { return *command_; }
  graph::OutputSignal<Eigen::VectorXd>& configuration_output() { return *configuration_; }
  graph::OutputSignal<Eigen::VectorXd>& velocity_output() { return *velocity_; }

 private:
  void UpdateConfiguration(const graph::Tick& t, const Eigen::VectorXd& q,
                           Eigen::VectorXd* next) const;
  void UpdateVelocity(const graph::Tick& t, const Eigen::VectorXd& v, Eigen::VectorXd* next) const;

  ModelPtr model_;
  graph::InputSignal<Eigen::VectorXd>* command_{};
  graph::OutputSignal<Eigen::VectorXd>* configuration_{};
  graph::OutputSignal<Eigen::VectorXd>* velocity_{};
  mutable Eigen::VectorXd step_;  // scratch v dt (nv)
};

/// Throws SotError (naming `who`) unless q is a valid configuration of `model`: size nq, finite,
/// unit quaternions / unit complex numbers where the joints have them.
void CheckConfiguration(const pinocchio::Model& model, const Eigen::VectorXd& q,
                        const std::string& who);

}  // namespace marionette::sot
