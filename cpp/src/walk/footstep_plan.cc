#include "marionette/walk/footstep_plan.h"

#include <cmath>

namespace marionette::walk {

std::string ValidateFootstepPlan(const FootstepPlan& plan, const FootstepLimits& limits) {
  if (plan.num_steps < 0 || plan.num_steps > FootstepPlan::kMaxSteps) {
    return "plan " + std::to_string(plan.plan_id) + " has " + std::to_string(plan.num_steps) +
           " steps (at most " + std::to_string(FootstepPlan::kMaxSteps) + ")";
  }
  if (plan.first_step_index < 0) return "first_step_index must be >= 0";
  for (int k = 0; k < plan.num_steps; ++k) {
    const Footstep& s = plan.steps[k];
    const std::string who =
        "step " + std::to_string(k) + " (index " + std::to_string(s.index) + "): ";
    if (s.index != plan.first_step_index + k) {
      return who + "indices must run from first_step_index " +
             std::to_string(plan.first_step_index) + " without gaps";
    }
    if (!s.placement.allFinite()) return who + "non-finite placement";
    if (!(s.single_support >= limits.min_single_support &&
          s.single_support <= limits.max_single_support)) {
      return who + "single support " + std::to_string(s.single_support) + " s outside [" +
             std::to_string(limits.min_single_support) + ", " +
             std::to_string(limits.max_single_support) + "]";
    }
    if (!(s.double_support >= 0.0 && s.double_support <= limits.max_double_support)) {
      return who + "double support " + std::to_string(s.double_support) + " s outside [0, " +
             std::to_string(limits.max_double_support) + "]";
    }
    if (!(s.step_height >= 0.0 && s.step_height <= limits.max_step_height)) {
      return who + "step height " + std::to_string(s.step_height) + " m outside [0, " +
             std::to_string(limits.max_step_height) + "]";
    }
    if (s.num_via < 0 || s.num_via > SwingFoot::kMaxVia) {
      return who + std::to_string(s.num_via) + " via points (at most " +
             std::to_string(SwingFoot::kMaxVia) + ")";
    }
    for (int i = 0; i < s.num_via; ++i) {
      if (!s.via[i].allFinite()) return who + "non-finite via point";
    }
  }
  return "";
}

}  // namespace marionette::walk
