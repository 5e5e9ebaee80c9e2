#pragma once
/// Footstep plans as the controller holds them: fixed-capacity values (copied between the LCM
/// thread and the loop without allocation), the same fields as lcmt_footstep_plan.
///
/// Step indices are global and stable (python/marionette/footsteps/node.py): step i of a plan
/// keeps index i in every replan; a replan carries the steps from `first_step_index` on.
/// Timing of step i: a double support of `double_support` seconds (the ZMP moves onto the foot
/// that stays), then a single support of `single_support` seconds (the other foot swings).

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <string>

#include "marionette/walk/swing_foot.h"

namespace marionette::walk {

struct Footstep {
  int index = 0;                                    ///< global step index
  bool is_left = true;                              ///< the left foot moves
  FootPlacement placement = FootPlacement::Zero();  ///< landing sole placement (x y z yaw), world
  double single_support = 0.8;                      ///< [s] swing duration
  double double_support = 0.2;                      ///< [s] before the swing
  double step_height = 0.05;  ///< [m] swing apex above the lift-off/landing line
  int num_via = 0;            ///< swing passage points
  std::array<Eigen::Vector3d, SwingFoot::kMaxVia> via{};  ///< world [m]
};

struct FootstepPlan {
  static constexpr int kMaxSteps = 64;
  int64_t plan_id = 0;
  int first_step_index = 0;  ///< index of steps[0]
  bool stop_at_end = true;
  int num_steps = 0;
  std::array<Footstep, kMaxSteps> steps{};
  int64_t source_hash = 0;  ///< names the message it came from (the controller's journal)
};

/// Limits a plan must respect (checked before it reaches the loop).
struct FootstepLimits {
  double min_single_support = 0.1, max_single_support = 10.0;  ///< [s]
  double max_double_support = 10.0;                            ///< [s]
  double max_step_height = 0.5;                                ///< [m]
};

/// Why `plan` cannot be executed ("" when it can): step count, consecutive indices from
/// first_step_index, finite placements, durations and heights within `limits`, via points.
std::string ValidateFootstepPlan(const FootstepPlan& plan, const FootstepLimits& limits = {});

}  // namespace marionette::walk
