#pragma once
/// Gripper admittance (Nicolin 2022 §3.2.4.3, eq. 3.11–3.13): one gripper joint, position control
/// until the estimated grip force crosses a threshold, then admittance q̇ = K_a (f* − f̂) to hold
/// f* (≈ 5 N); release in reverse (admittance towards 0 N, then position control to open).
///
/// Force estimate from the motor current I (the simulator's actuator force stands for it):
///   τ_motor = k_τ I (3.11),  τ = k_gear τ_motor (3.12),  f = τ / d_axis-gripper (3.13)
///   f̂ = s · k_τ k_gear · I / d       s = closing direction (+1 or −1): f̂ > 0 squeezes.
/// f̂ is low-passed by a first-order filter (cut-off f_c = 5 Hz in the thesis), discretised
/// exactly for the period dt:  y_{k+1} = y_k + α (f̂_k − y_k),  α = 1 − exp(−2π f_c dt).
///
/// Phases (the state machine; switch tests on the filtered force y):
///   0 closing    position control towards `position_target` along a ramp (speed, acceleration)
///                that starts where the joint is, at the speed it was commanded the tick before
///                (applied_velocity: a controller switched in while the fingers still close goes
///                on closing, with no velocity step); y > force_threshold → 1
///   1 holding    admittance   q̇ = s K_a (f* − y)
///   2 releasing  admittance   q̇ = s K_a (f_r − y), f_r ramped from the force held to 0 N at
///                release_rate;  y < release_force → 3
///   3 opening    position control towards `position_target` (the open position)
///   `release` true moves 0/1 to 2 (or straight to 3 when y < release_force); false moves 3 to 0.
///   With `release_after` > 0 a releasing task starts in 1 and holds for that long first (a
///   hand-over: the other gripper closes on the object meanwhile), counted from its first tick:
///   the force held on that tick (within [0, f*]; f* while the object is squeezed), so its first
///   command is the previous controller's (0 N held — fingers at their limit, closed on nothing
///   as on the dry run's kinematic backend — commands nothing, where f* commanded K_a f*).
/// As a feature (1 row, J = unit row of the joint, ė = J v + ∂e/∂t):
///   position phases   e = q − r (r the ramp),       ∂e/∂t = −ṙ      (the task gives v = ṙ − λe)
///   admittance phases e = s K_a (y − f*) / λ,       ∂e/∂t = 0       (the task gives v = s K_a (f*
///   − y))
/// so λ (the task's constant gain, `task_gain`) must be the Task's gain. ‖e‖ → 0 when the ramp
/// reaches the target or the force reaches its target.
/// @entity  inputs: kinematics (q: the commanded joint), effort (nv, actuator force/torque per
///          dof, MujocoDevice.effort), q_measured (nq, for reporting; default: unplugged = none),
///          applied_velocity (nv, the command applied the tick before; default: at rest),
///          position_target (settable), release (bool, settable)
///          states: machine (phase, y, r, primed, ṙ, elapsed, f_r)
///          outputs: terms, error, jacobian, force (f̂ [N] unfiltered), force_filtered (y [N]),
///          phase, measured_position (the joint in q_measured [rad])

#include <Eigen/Core>
#include <string>

#include "marionette/sot/feature.h"

namespace marionette::sot {

struct GripperAdmittanceOptions {
  double force_target = 5.0;     ///< f* [N] held in phase 1
  double force_threshold = 4.0;  ///< [N] closing → holding when y exceeds it (below f*)
  double release_force = 0.5;    ///< [N] releasing → opening when y drops below it
  double admittance_gain =
      0.02;                ///< K_a [rad/(s N)] (with a 500 N/rad grip: ζ ≈ 0.9 with the filter)
  double lever_arm = 0.1;  ///< d_axis-gripper [m], eq. 3.13
  double torque_per_effort = 1.0;  ///< k_τ k_gear [N m per unit of effort], eq. 3.11–3.12
  double cutoff_frequency = 5.0;   ///< f_c [Hz] of the force low-pass
  double speed = 0.1;  ///< [rad/s] position ramp speed ("slowly", §3.2.4.3: the friction and
                       ///< damping it costs read as force)
  double acceleration = 1.0;  ///< [rad/s²] of the ramp (starts and stops without a velocity step)
  double closing_direction = -1.0;  ///< s: sign of q̇ when closing (−1 when closed < open)
  double release_after = 0.0;  ///< [s] a releasing task holds the grip this long before releasing
  double release_rate = 10.0;  ///< [N/s] the releasing force target's ramp to 0 N
  double task_gain = 2.0;      ///< λ [1/s] of the Task that reads this feature
  double dt = 1e-3;            ///< control period [s]
  /// Throws SotError naming `who` when a value is out of range.
  void Check(const std::string& who) const;
};

/// Phases of FeatureGripperAdmittance (the `phase` output as a double).
enum class GripperPhase : int { kClosing = 0, kHolding = 1, kReleasing = 2, kOpening = 3 };

class FeatureGripperAdmittance final : public Feature {
 public:
  /// `joint`: the gripper's 1-DoF joint; `position_target`: where position control goes (closed
  /// or open position); `release`: start releasing. Throws SotError on an unknown joint, a joint
  /// with more than one DoF or bad options.
  FeatureGripperAdmittance(std::string name, ModelPtr model, const std::string& joint,
                           double position_target, bool release, GripperAdmittanceOptions options);
  const char* type_name() const override { return "FeatureGripperAdmittance"; }

  graph::InputSignal<Eigen::VectorXd>& effort_input() { return *effort_; }
  graph::InputSignal<Eigen::VectorXd>& q_measured_input() { return *q_measured_; }
  graph::InputSignal<Eigen::VectorXd>& applied_velocity_input() { return *applied_velocity_; }
  graph::InputSignal<double>& position_target_input() { return *position_target_; }
  graph::InputSignal<bool>& release_input() { return *release_; }
  graph::OutputSignal<double>& force_output() { return *force_; }
  graph::OutputSignal<double>& force_filtered_output() { return *force_filtered_; }
  graph::OutputSignal<double>& phase_output() { return *phase_; }
  graph::OutputSignal<double>& measured_position_output() { return *measured_position_; }
  const GripperAdmittanceOptions& options() const { return options_; }
  /// α = 1 − exp(−2π f_c dt) of the exact first-order discretisation.
  double filter_alpha() const { return alpha_; }
  int joint_q() const { return iq_; }
  int joint_v() const { return iv_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;
  void CalcForce(const graph::Tick& t, double* out) const;
  void CalcForceFiltered(const graph::Tick& t, double* out) const;
  void CalcPhase(const graph::Tick& t, double* out) const;
  void CalcMeasuredPosition(const graph::Tick& t, double* out) const;
  void UpdateMachine(const graph::Tick& t, const Eigen::VectorXd& x, Eigen::VectorXd* next) const;
  // ṙ of the position ramp at r (moving at `rate`) towards the target: trapezoidal (|ṙ| <= speed,
  // |r̈| <= acceleration), stopping on the target.
  double RampRate(double r, double rate, double target) const;
  // The ramp's speed in state x: the state's, or on the first tick the joint's applied velocity
  // (within ±speed).
  double RampRateNow(const graph::Tick& t, const Eigen::VectorXd& x) const;
  // Filtered force y this tick: the state, or f̂ itself on the first tick (the filter starts at
  // the current force, so a releasing controller starts from the force being held).
  double FilteredNow(const graph::Tick& t, const Eigen::VectorXd& x) const;
  // The force target [N] of an admittance phase in state x, y the filtered force this tick.
  double AdmittanceTarget(const Eigen::VectorXd& x, double y) const;

  GripperAdmittanceOptions options_;
  double alpha_;
  bool holds_what_was_held_;  // a releasing task that waits: holds the force of its first tick
  int iq_, iv_;
  graph::InputSignal<Eigen::VectorXd>* effort_{};
  graph::InputSignal<Eigen::VectorXd>* q_measured_{};
  graph::InputSignal<Eigen::VectorXd>* applied_velocity_{};
  graph::InputSignal<double>* position_target_{};
  graph::InputSignal<bool>* release_{};
  graph::OutputSignal<Eigen::VectorXd>* machine_{};  // (phase, y, r, primed, ṙ, elapsed, f_r)
  graph::OutputSignal<double>* force_{};
  graph::OutputSignal<double>* force_filtered_{};
  graph::OutputSignal<double>* phase_{};
  graph::OutputSignal<double>* measured_position_{};
};

}  // namespace marionette::sot
