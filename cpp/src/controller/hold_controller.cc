#include "marionette/controller/hold_controller.h"

#include <algorithm>
#include <limits>
#include <stdexcept>

#include "marionette/sot/feature_com.h"

namespace marionette::controller {
namespace {

lcmt_task_spec Task(const std::string& name, const std::string& kind, int priority,
                    const std::string& frame, double gain) {
  lcmt_task_spec t{};
  t.name = name;
  t.kind = kind;
  t.priority = priority;
  t.frame = frame;
  t.gain = gain;
  return t;  // no reference: "hold where it is" at the swap
}

}  // namespace

lcmt_controller_spec HoldControllerSpec(const std::vector<std::string>& soles,
                                        const std::vector<lcmt_task_spec>& balance_tasks) {
  lcmt_controller_spec spec{};
  spec.controller_id = kHoldControllerId;
  spec.name = !balance_tasks.empty() ? "hold (stop walking + posture)"
              : soles.empty()        ? "hold (posture)"
                                     : "hold (balance + posture)";
  // Engaged by the loop, not through the start check: the solver's switch blend (eq. 2.34)
  // keeps the command continuous.
  spec.max_switch_velocity_jump = std::numeric_limits<double>::max();
  spec.reference_timeout = 0.0;  // nothing streamed
  if (!balance_tasks.empty()) {
    for (lcmt_task_spec t : balance_tasks) {  // the walk's own gains, frames and masks
      t.name = "hold_" + t.name;
      t.priority = 0;
      spec.tasks.push_back(t);
    }
  } else {
    // The walking stack's gain for the feet (20/s); the CoM moves over the support with a time
    // constant of 0.5 s (2/s): a 5 cm shift starts at 0.1 m/s, quasi-static.
    for (size_t i = 0; i < soles.size(); ++i) {
      spec.tasks.push_back(Task("hold_sole_" + std::to_string(i), "se3", 0, soles[i], 20.0));
    }
    if (!soles.empty()) spec.tasks.push_back(Task("hold_com", "com", 0, "", 2.0));
  }
  // Posture 2/s, as every stack's last level.
  spec.tasks.push_back(Task("hold_posture", "posture", soles.empty() ? 0 : 1, "", 2.0));
  spec.num_tasks = static_cast<int32_t>(spec.tasks.size());
  return spec;
}

std::unique_ptr<BuiltController> BuildHoldController(
    const ControllerFactory& factory, const graph::Graph& graph, const BuiltController& running,
    const Eigen::VectorXd& q, const sot::ModelPtr& model, const std::vector<std::string>& soles) {
  if (running.walk_steps != nullptr) {
    // The walk's entities stay in the graph (the hold adopts them); the rest goes.
    std::vector<std::string> replaced;
    for (const std::string& name : running.entity_names) {
      if (name != running.walk_steps->name() && name != running.walk_pattern->name())
        replaced.push_back(name);
    }
    const lcmt_controller_spec spec = HoldControllerSpec(soles, running.balance_tasks);
    std::unique_ptr<BuiltController> built = factory.Build(spec, graph, replaced, q, &running);
    walk::FootstepManager* steps = built->walk_steps;
    built->holds.push_back([steps](const sot::Kinematics&) { steps->StopAfterCurrentStep(); });
    return built;
  }
  const lcmt_controller_spec spec = HoldControllerSpec(soles);
  std::unique_ptr<BuiltController> built = factory.Build(spec, graph, running.entity_names, q);
  if (soles.empty()) return built;

  // The factory's hold set the CoM reference to the current CoM; this one, run after it, moves
  // its horizontal part over the support.
  const std::string com_feature = "c" + std::to_string(spec.controller_id) + "_hold_com_feature";
  auto* com = dynamic_cast<sot::FeatureCom*>(built->edit->FindEntity(com_feature));
  if (com == nullptr)
    throw std::logic_error("hold controller: the factory built no '" + com_feature + "'");
  std::vector<sot::FrameRef> frames;
  for (const std::string& sole : soles)
    frames.push_back(sot::MakeFrameRef(*model, sole, "hold controller"));
  auto* reference = &com->reference_input();
  auto scratch = std::make_shared<Eigen::VectorXd>(Eigen::VectorXd::Zero(3));
  built->holds.push_back([frames, reference, scratch](const sot::Kinematics& k) {
    double lowest = std::numeric_limits<double>::infinity();
    for (const sot::FrameRef& f : frames)
      lowest = std::min(lowest, k.placement(f).translation().z());
    Eigen::Vector2d centre = Eigen::Vector2d::Zero();
    int on_ground = 0;
    for (const sot::FrameRef& f : frames) {
      const Eigen::Vector3d p = k.placement(f).translation();
      if (p.z() <= lowest + kSupportHeight) centre += p.head<2>(), ++on_ground;
    }
    Eigen::VectorXd& c = *scratch;
    c = k.com();
    c.head<2>() = centre / on_ground;  // at least the lowest sole
    reference->SetValue(c);
  });
  return built;
}

}  // namespace marionette::controller
