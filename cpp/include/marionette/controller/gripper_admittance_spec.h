#pragma once
/// The `gripper_admittance` task kind of a controller spec (thesis 000 §3.2.4.3, §3.2.5: "the
/// transition where the robot closes its gripper ... adds the position and admittance tasks"):
/// how an lcmt_task_spec declares a sot::FeatureGripperAdmittance.
///   joint_name   exactly one: the gripper joint (robot.yaml grippers[].joint)
///   reference    1 value: the position-control target [rad] (closed position when closing,
///                open position when releasing); required
///   gain         λ of the task (constant: gain_slope must be 0); 0 = the factory's default
///   frame, frame_b, reference_channel, mask: unused (must be empty / all false)
///   parameters   (all optional; GripperAdmittanceOptions' defaults)
///     force_target [N], force_threshold [N], release_force [N], admittance_gain [rad/(s N)],
///     lever_arm [m], torque_per_effort [N m per effort unit], cutoff_frequency [Hz],
///     speed [rad/s], acceleration [rad/s²], closing_direction (+1 | -1), release (0 | 1),
///     release_after [s] (a releasing task holds the grip that long first: a hand-over),
///     release_rate [N/s] (the releasing force target's ramp to 0 N)

#include <string>

#include "marionette/lcmt_task_spec.hpp"
#include "marionette/sot/feature_gripper_admittance.h"

namespace marionette::controller {

inline constexpr char kGripperAdmittanceKind[] = "gripper_admittance";

struct GripperAdmittanceSpec {
  std::string joint;
  double position_target = 0.0;
  bool release = false;
  sot::GripperAdmittanceOptions options;
};

/// Reads and checks a gripper_admittance task spec; `gain` is the task's λ (already defaulted).
/// Throws std::invalid_argument naming `who` and the field (unknown parameter, missing joint or
/// reference, a stream or an adaptive gain, out-of-range values).
GripperAdmittanceSpec ParseGripperAdmittance(const lcmt_task_spec& task, double gain,
                                             const std::string& who);

}  // namespace marionette::controller
