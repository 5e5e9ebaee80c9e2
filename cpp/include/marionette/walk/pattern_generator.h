#pragma once
/// PatternGenerator: the CoM reference of a walk from the ZMP reference window by preview
/// control on the cart-table model (Dang 2012 §2.4.4 eq. 2.56, §2.6.2 fig. 2.25). Plugged after
/// a FootstepManager (zmp_window), its outputs feed the CoM task (reference and feed-forward).
///
/// The cart state (c, ċ, c̈ per horizontal axis and the running ZMP error sums) is a state
/// signal: during tick k the outputs give x(k); after the tick x(k+1) = A x(k) + B u(k) with the
/// jerk u(k) of eq. 2.56 from the window seen at tick k. The CoM height is constant.
/// @entity  inputs: zmp_window (2 x (N+1), world [m]: p_ref(k) ... p_ref(k+N))
///          state: cart (8: cx ċx c̈x cy ċy c̈y Σex Σey)
///          outputs: com (3, world [m]), com_velocity (3), com_acceleration (3),
///                   zmp (2: the cart-table ZMP c − (z_c/g) c̈ of the output, eq. 2.51)

#include <Eigen/Core>
#include <memory>
#include <string>

#include "marionette/graph/entity.h"
#include "marionette/walk/preview_control.h"

namespace marionette::walk {

class PatternGenerator final : public graph::Entity {
 public:
  /// Gains for `params` (computed here: call off the loop), starting at rest at `com` (world;
  /// its height is held; params.com_height is the height above the ground the gains assume).
  PatternGenerator(std::string name, const PreviewControlParams& params,
                   const Eigen::Vector3d& com);
  /// Same with gains already computed (shared between controllers with the same parameters).
  PatternGenerator(std::string name, std::shared_ptr<const PreviewGains> gains,
                   const Eigen::Vector3d& com);
  const char* type_name() const override { return "PatternGenerator"; }

  /// Loop thread, between ticks: at rest at `com` (zero velocity and acceleration, error sums
  /// cleared). No allocation.
  void Reset(const Eigen::Vector3d& com);
  const PreviewGains& gains() const { return *gains_; }
  int preview_samples() const { return static_cast<int>(gains_->Gp.size()); }

  graph::InputSignal<Eigen::MatrixXd>& zmp_window_input() { return *zmp_window_; }
  graph::OutputSignal<Eigen::VectorXd>& cart_output() { return *cart_; }
  graph::OutputSignal<Eigen::VectorXd>& com_output() { return *com_; }
  graph::OutputSignal<Eigen::VectorXd>& com_velocity_output() { return *com_velocity_; }
  graph::OutputSignal<Eigen::VectorXd>& com_acceleration_output() { return *com_acceleration_; }
  graph::OutputSignal<Eigen::VectorXd>& zmp_output() { return *zmp_; }

 private:
  void UpdateCart(const graph::Tick& t, const Eigen::VectorXd& x, Eigen::VectorXd* next) const;
  void CalcCom(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcComVelocity(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcComAcceleration(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcZmp(const graph::Tick& t, Eigen::VectorXd* out) const;

  std::shared_ptr<const PreviewGains> gains_;
  double com_z_;
  graph::InputSignal<Eigen::MatrixXd>* zmp_window_{};
  graph::OutputSignal<Eigen::VectorXd>* cart_{};
  graph::OutputSignal<Eigen::VectorXd>* com_{};
  graph::OutputSignal<Eigen::VectorXd>* com_velocity_{};
  graph::OutputSignal<Eigen::VectorXd>* com_acceleration_{};
  graph::OutputSignal<Eigen::VectorXd>* zmp_{};
};

}  // namespace marionette::walk
