#include "marionette/controller/gripper_admittance_spec.h"

#include <algorithm>
#include <map>
#include <stdexcept>

namespace marionette::controller {

GripperAdmittanceSpec ParseGripperAdmittance(const lcmt_task_spec& t, double gain,
                                             const std::string& who) {
  const auto fail = [&who](const std::string& what) {
    throw std::invalid_argument(who + ": " + what);
  };
  GripperAdmittanceSpec out;
  if (t.num_joints != 1 || t.joint_name.size() != 1 || t.joint_name[0].empty()) {
    fail("a gripper_admittance task names exactly one joint (the gripper's) in joint_name");
  }
  out.joint = t.joint_name[0];
  if (t.num_reference != 1 || t.reference.size() != 1) {
    fail("a gripper_admittance task needs its position target as a 1-value reference (got " +
         std::to_string(t.num_reference) + " values)");
  }
  out.position_target = t.reference[0];
  if (!t.reference_channel.empty()) fail("a gripper_admittance reference cannot be streamed");
  if (!t.frame.empty() || !t.frame_b.empty()) fail("a gripper_admittance task takes no frame");
  if (std::any_of(std::begin(t.mask), std::end(t.mask), [](bool b) { return b; })) {
    fail("a gripper_admittance task takes no mask");
  }
  if (t.gain_slope > 0.0) fail("a gripper_admittance task needs a constant gain (gain_slope 0)");
  sot::GripperAdmittanceOptions& o = out.options;
  o.task_gain = gain;
  const std::map<std::string, double*> fields = {{"force_target", &o.force_target},
                                                 {"force_threshold", &o.force_threshold},
                                                 {"release_force", &o.release_force},
                                                 {"admittance_gain", &o.admittance_gain},
                                                 {"lever_arm", &o.lever_arm},
                                                 {"torque_per_effort", &o.torque_per_effort},
                                                 {"cutoff_frequency", &o.cutoff_frequency},
                                                 {"speed", &o.speed},
                                                 {"acceleration", &o.acceleration},
                                                 {"closing_direction", &o.closing_direction},
                                                 {"release_after", &o.release_after},
                                                 {"release_rate", &o.release_rate}};
  for (int i = 0; i < t.num_parameters; ++i) {
    const std::string& name = t.parameter_name[i];
    const double value = t.parameter_value[i];
    if (name == "release") {
      if (value != 0.0 && value != 1.0) fail("parameter 'release' must be 0 or 1");
      out.release = value == 1.0;
      continue;
    }
    const auto it = fields.find(name);
    if (it == fields.end()) {
      std::string known = "release";
      for (const auto& [n, p] : fields) known += ", " + n;
      fail("unknown parameter '" + name + "' (" + known + ")");
    }
    *it->second = value;
  }
  try {
    o.Check(who);
  } catch (const sot::SotError& e) {
    throw std::invalid_argument(e.what());
  }
  return out;
}

}  // namespace marionette::controller
