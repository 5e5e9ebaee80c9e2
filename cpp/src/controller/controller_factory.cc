#include "marionette/controller/controller_factory.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <set>
#include <stdexcept>

#include "marionette/controller/gripper_admittance_spec.h"
#include "marionette/lcm/channels.h"
#include "marionette/sot/feature_com.h"
#include "marionette/sot/feature_gaze.h"
#include "marionette/sot/feature_position.h"
#include "marionette/sot/feature_posture.h"
#include "marionette/sot/feature_relative_se3.h"
#include "marionette/sot/feature_se3.h"
#include "marionette/sot/joint_limits.h"
#include "marionette/sot/solver.h"

namespace marionette::controller {
namespace {

using Kind = ReferenceStream::Kind;

[[noreturn]] void Fail(const std::string& where, const std::string& what) {
  throw std::invalid_argument(where + ": " + what);
}

// (x y z qw qx qy qz) into a 7-vector already of that size: no allocation (loop thread).
void WritePose(const pinocchio::SE3& X, Eigen::VectorXd* v) {
  const Eigen::Quaterniond q(X.rotation());
  (*v) << X.translation(), q.w(), q.x(), q.y(), q.z();
}

pinocchio::SE3 VectorToPose(const Eigen::VectorXd& v) {
  return pinocchio::SE3(Eigen::Quaterniond(v[3], v[4], v[5], v[6]).normalized().toRotationMatrix(),
                        v.head<3>());
}

// lcmt_task_spec.mask as a feature mask over n components; all false means all (LCM's default).
// Task kinds whose reference is a pose (xyz + quaternion, 7 values; velocity 6).
bool IsPoseKind(const std::string& kind) {
  return kind == "se3" || kind == "pbvs" || kind == "relative_se3";
}

sot::Mask MaskOf(const lcmt_task_spec& spec, int n) {
  sot::Mask mask(spec.mask, spec.mask + n);
  if (std::none_of(mask.begin(), mask.end(), [](bool b) { return b; })) return {};
  return mask;
}

// Walking: a FootstepManager and a PatternGenerator for the tasks whose reference_channel is
// "walk:<role>" (controller_factory.h), starting standing at the configuration of `now`.
constexpr char kWalkPrefix[] = "walk:";

void AddWalking(const lcmt_controller_spec& spec, const std::string& where,
                const std::string& prefix, const sot::Kinematics& now, graph::GraphEdit& edit,
                const BuiltController* continue_walk, BuiltController* built) {
  std::map<std::string, const lcmt_task_spec*> roles;  // left_foot, right_foot, com, waist
  for (const lcmt_task_spec& t : spec.tasks) {
    if (t.reference_channel.rfind(kWalkPrefix, 0) != 0) continue;
    const std::string who = where + ", task '" + t.name + "'";
    const std::string role = t.reference_channel.substr(std::strlen(kWalkPrefix));
    if (role != "left_foot" && role != "right_foot" && role != "com" && role != "waist") {
      Fail(who, "unknown walk reference '" + t.reference_channel +
                    "' (walk:left_foot, walk:right_foot, walk:com, walk:waist)");
    }
    const std::string kind = role == "com" ? "com" : "se3";
    if (t.kind != kind)
      Fail(who, "a '" + t.reference_channel + "' reference needs a " + kind + " task");
    if (t.num_reference != 0)
      Fail(who, "a walk reference comes from the pattern generator: give no fixed reference");
    if (!roles.emplace(role, &t).second) Fail(who, "two tasks take '" + t.reference_channel + "'");
  }
  if (roles.empty()) return;
  if (roles.count("left_foot") == 0 || roles.count("right_foot") == 0) {
    Fail(
        where,
        "walking needs a walk:left_foot and a walk:right_foot se3 task (the soles it starts from)");
  }
  if (continue_walk != nullptr) {  // adopt the running walk as it is
    if (continue_walk->walk_steps == nullptr)
      Fail(where, "the controller to continue does not walk");
    built->walk_steps = continue_walk->walk_steps;
    built->walk_pattern = continue_walk->walk_pattern;
    built->entity_names.push_back(built->walk_steps->name());
    built->entity_names.push_back(built->walk_pattern->name());
    return;
  }
  try {
    const pinocchio::Model& model = now.model();
    const sot::FrameRef left = sot::MakeFrameRef(model, roles["left_foot"]->frame, where);
    const sot::FrameRef right = sot::MakeFrameRef(model, roles["right_foot"]->frame, where);
    const walk::FootPlacement l = walk::PoseToPlacement(now.placement(left));
    const walk::FootPlacement r = walk::PoseToPlacement(now.placement(right));
    const Eigen::Vector3d com = now.com();
    walk::FootstepManagerOptions options;  // dt = 1 ms, the controller's period; 1.6 s preview
    auto& steps =
        edit.Add<walk::FootstepManager>(prefix + "walk_steps", l, r, com.head<2>(), options);
    walk::PreviewControlParams params;
    params.dt = options.dt;
    params.preview_time = options.preview_samples * options.dt;
    params.com_height = com.z() - 0.5 * (l.z() + r.z());  // cart-table height above the soles
    auto& pattern = edit.Add<walk::PatternGenerator>(prefix + "walk_pattern", params, com);
    built->entity_names.push_back(steps.name());
    built->entity_names.push_back(pattern.name());
    edit.Connect(steps.zmp_window_output(), pattern.zmp_window_input());
    built->walk_steps = &steps;
    built->walk_pattern = &pattern;
    // At the swap: standing where the robot is, the CoM at rest where it is, the waist facing
    // where it does.
    const std::optional<sot::FrameRef> waist =
        roles.count("waist") ? std::optional(sot::MakeFrameRef(model, roles["waist"]->frame, where))
                             : std::nullopt;
    built->holds.push_back(
        [left, right, waist, s = &steps, p = &pattern](const sot::Kinematics& k) {
          const Eigen::Vector3d c = k.com();
          s->Reset(walk::PoseToPlacement(k.placement(left)),
                   walk::PoseToPlacement(k.placement(right)), c.head<2>());
          if (waist) s->HoldWaist(k.placement(*waist).rotation());
          p->Reset(c);
        });
  } catch (const std::invalid_argument& e) {  // sot::SotError, bad preview parameters
    Fail(where, std::string("walking: ") + e.what());
  } catch (const std::runtime_error& e) {
    Fail(where, std::string("walking: ") + e.what());
  }
}

void ConnectWalkReference(const std::string& channel, const BuiltController& built,
                          graph::GraphEdit& edit, graph::SignalBase& reference,
                          graph::SignalBase& reference_velocity) {
  const std::string role = channel.substr(std::strlen(kWalkPrefix));
  if (role == "com") {
    edit.Connect(built.walk_pattern->com_output(), reference);
    edit.Connect(built.walk_pattern->com_velocity_output(), reference_velocity);
  } else if (role == "waist") {
    edit.Connect(built.walk_steps->waist_output(), reference);
    edit.Connect(built.walk_steps->waist_velocity_output(), reference_velocity);
  } else if (role == "left_foot") {
    edit.Connect(built.walk_steps->left_foot_output(), reference);
    edit.Connect(built.walk_steps->left_foot_velocity_output(), reference_velocity);
  } else {
    edit.Connect(built.walk_steps->right_foot_output(), reference);
    edit.Connect(built.walk_steps->right_foot_velocity_output(), reference_velocity);
  }
}

}  // namespace

ControllerFactory::ControllerFactory(sot::ModelPtr model, ControllerSockets sockets,
                                     double default_gain, std::vector<int> held_velocities)
    : model_(std::move(model)),
      sockets_(sockets),
      default_gain_(default_gain),
      held_velocities_(std::move(held_velocities)) {}

std::pair<int, int> ControllerFactory::ReferenceSizes(const std::string& kind) const {
  if (IsPoseKind(kind)) return {7, 6};
  if (kind == "position" || kind == "com" || kind == "gaze") return {3, 3};
  if (kind == "posture") return {model_->nq, model_->nv};
  if (kind == kGripperAdmittanceKind) return {1, 1};  // the position-control target
  throw std::invalid_argument(
      "unknown task kind '" + kind +
      "' (se3, pbvs, relative_se3, position, com, posture, gaze, gripper_admittance)");
}

std::unique_ptr<BuiltController> ControllerFactory::Build(
    const lcmt_controller_spec& spec, const graph::Graph& graph,
    const std::vector<std::string>& previous_entities, const Eigen::VectorXd& q,
    const BuiltController* continue_walk) const {
  const std::string where =
      "controller '" + spec.name + "' (id " + std::to_string(spec.controller_id) + ")";
  if (spec.num_tasks != static_cast<int>(spec.tasks.size()) || spec.num_tasks < 1) {
    Fail(where, "needs at least one task (num_tasks " + std::to_string(spec.num_tasks) + ")");
  }
  if (!(spec.max_switch_velocity_jump > 0.0) || !std::isfinite(spec.max_switch_velocity_jump)) {
    Fail(where, "max_switch_velocity_jump must be a positive number");
  }
  if (!(spec.reference_timeout >= 0.0) || !std::isfinite(spec.reference_timeout)) {
    Fail(where, "reference_timeout must be >= 0");
  }
  if (q.size() != model_->nq || !q.allFinite()) Fail(where, "no valid current configuration");

  auto built = std::make_unique<BuiltController>();
  built->id = spec.controller_id;
  built->name = spec.name;
  built->max_switch_velocity_jump = spec.max_switch_velocity_jump;
  built->reference_timeout = spec.reference_timeout > 0.0 ? spec.reference_timeout : 0.1;
  built->edit = std::make_unique<graph::GraphEdit>(graph);
  graph::GraphEdit& edit = *built->edit;
  for (const std::string& name : previous_entities) edit.Remove(name);

  sot::Kinematics now(model_);
  now.Compute(q);
  const std::string prefix = "c" + std::to_string(spec.controller_id) + "_";
  std::map<int, std::vector<sot::Task*>> by_priority;
  std::set<std::string> names;

  const auto add = [&](auto& entity) -> decltype(entity)& {
    built->entity_names.push_back(entity.name());
    return entity;
  };
  AddWalking(spec, where, prefix, now, edit, continue_walk, built.get());
  int first_level = 100;
  for (const lcmt_task_spec& t : spec.tasks) first_level = std::min(first_level, t.priority);
  for (const lcmt_task_spec& t : spec.tasks) {
    const bool streamed =
        !t.reference_channel.empty() && t.reference_channel.rfind(kWalkPrefix, 0) != 0;
    if (t.priority == first_level && !streamed &&
        (t.kind == "se3" || t.kind == "position" || t.kind == "com")) {
      built->balance_tasks.push_back(t);
    }
  }

  for (const lcmt_task_spec& t : spec.tasks) {
    const std::string who = where + ", task '" + t.name + "'";
    if (t.name.empty() || t.name.find_first_of(". ") != std::string::npos) {
      Fail(who, "a task needs a name without spaces or dots");
    }
    if (!names.insert(t.name).second) Fail(who, "two tasks have this name");
    if (t.priority < 0 || t.priority > 100) Fail(who, "priority must be in [0, 100]");
    // A reference comes from nowhere else: an unknown name is refused, never taken as streamed.
    if (!t.reference_channel.empty() && t.reference_channel != channels::kTaskReference &&
        t.reference_channel.rfind(kWalkPrefix, 0) != 0) {
      Fail(who, "unknown reference_channel '" + t.reference_channel + "' (\"\" fixed, " +
                    channels::kTaskReference +
                    " streamed, walk:left_foot, walk:right_foot, walk:com, walk:waist)");
    }
    if (!(t.gain > 0.0) && t.gain != 0.0) Fail(who, "gain must be >= 0");
    for (double x : {t.gain, t.gain_max, t.gain_slope}) {
      if (!std::isfinite(x) || x < 0.0) Fail(who, "gains must be finite and >= 0");
    }
    if (t.num_reference != static_cast<int>(t.reference.size()) ||
        t.num_joints != static_cast<int>(t.joint_name.size()) ||
        t.num_parameters != static_cast<int>(t.parameter_name.size()) ||
        t.num_parameters != static_cast<int>(t.parameter_value.size())) {
      Fail(who, "array sizes disagree with their num_ fields");
    }
    for (double x : t.reference) {
      if (!std::isfinite(x)) Fail(who, "non-finite reference value");
    }
    if (t.num_parameters > 0 && t.kind != kGripperAdmittanceKind) {
      Fail(who, "unknown parameter '" + t.parameter_name[0] + "'");
    }

    const auto [value_size, derivative_size] = [&] {
      try {
        return ReferenceSizes(t.kind);
      } catch (const std::invalid_argument& e) {
        Fail(who, e.what());
      }
    }();
    if (t.num_reference != 0 && t.num_reference != value_size) {
      Fail(who, "reference has " + std::to_string(t.num_reference) + " values, a " + t.kind +
                    " task takes " + std::to_string(value_size));
    }
    // A pose reference (xyz + quaternion) by kind, never by size: a 7-value posture (a 6-DoF arm
    // with its gripper joint) is a vector.
    const bool se3 = IsPoseKind(t.kind);
    if (se3 && t.num_reference == 7) {
      const double n =
          Eigen::Vector4d(t.reference[3], t.reference[4], t.reference[5], t.reference[6]).norm();
      if (std::abs(n - 1.0) > 1e-3) Fail(who, "reference quaternion has norm " + std::to_string(n));
    }
    const double gain = t.gain > 0.0 ? t.gain : default_gain_;
    const sot::Gain g = t.gain_slope > 0.0 ? sot::Gain::Adaptive(gain, t.gain_max, t.gain_slope)
                                           : sot::Gain::Constant(gain);
    const std::string fname = prefix + t.name + "_feature";
    if (t.kind == kGripperAdmittanceKind) {  // its own reference and state machine
      const GripperAdmittanceSpec ga = ParseGripperAdmittance(t, gain, who);
      try {
        auto& f = add(edit.Add<sot::FeatureGripperAdmittance>(
            fname, model_, ga.joint, ga.position_target, ga.release, ga.options));
        edit.Connect(*sockets_.kinematics, f.kinematics_input());
        if (sockets_.effort) {
          edit.Connect(*sockets_.effort, f.effort_input());
        } else {  // kinematic backend: nothing measured, the gripper closes in position control
          f.effort_input().SetValue(Eigen::VectorXd::Zero(model_->nv));
        }
        if (sockets_.q_measured) edit.Connect(*sockets_.q_measured, f.q_measured_input());
        if (sockets_.applied_velocity) {
          edit.Connect(*sockets_.applied_velocity, f.applied_velocity_input());
        }
        auto& task = add(edit.Add<sot::Task>(prefix + t.name, f, sot::Gain::Constant(gain)));
        by_priority[t.priority].push_back(&task);
        built->task_names.push_back(t.name);
        built->task_errors.push_back(&task.error_norm_output());
      } catch (const std::invalid_argument& e) {
        Fail(who, e.what());
      } catch (const graph::GraphError& e) {
        Fail(who, e.what());
      }
      continue;
    }

    try {
      sot::Feature* feature = nullptr;
      graph::SignalBase* reference = nullptr;           // the feature's reference input
      graph::SignalBase* reference_velocity = nullptr;  // its feed-forward input
      // The feature's reference for zero error at a configuration (also checks the spec now).
      std::function<void(const sot::Kinematics&, Eigen::VectorXd*)> current;
      if (t.kind == "se3" || t.kind == "pbvs") {
        auto& f = add(edit.Add<sot::FeatureSE3>(fname, model_, t.frame, MaskOf(t, 6)));
        const sot::FrameRef frame = f.frame();
        current = [frame](const sot::Kinematics& k, Eigen::VectorXd* v) {
          WritePose(k.placement(frame), v);
        };
        feature = &f, reference = &f.reference_input(),
        reference_velocity = &f.reference_velocity_input();
      } else if (t.kind == "relative_se3") {
        auto& f =
            add(edit.Add<sot::FeatureRelativeSE3>(fname, model_, t.frame, t.frame_b, MaskOf(t, 6)));
        const sot::FrameRef a = sot::MakeFrameRef(*model_, t.frame, who);
        const sot::FrameRef b = sot::MakeFrameRef(*model_, t.frame_b, who);
        current = [a, b](const sot::Kinematics& k, Eigen::VectorXd* v) {
          WritePose(k.placement(b).actInv(k.placement(a)), v);
        };
        feature = &f, reference = &f.reference_input(),
        reference_velocity = &f.reference_velocity_input();
      } else if (t.kind == "position") {
        auto& f = add(edit.Add<sot::FeaturePosition>(fname, model_, t.frame, MaskOf(t, 3)));
        const sot::FrameRef frame = sot::MakeFrameRef(*model_, t.frame, who);
        current = [frame](const sot::Kinematics& k, Eigen::VectorXd* v) {
          *v = k.placement(frame).translation();
        };
        feature = &f, reference = &f.reference_input(),
        reference_velocity = &f.reference_velocity_input();
      } else if (t.kind == "com") {
        auto& f = add(edit.Add<sot::FeatureCom>(fname, model_, MaskOf(t, 3)));
        current = [](const sot::Kinematics& k, Eigen::VectorXd* v) { *v = k.com(); };
        feature = &f, reference = &f.reference_input(),
        reference_velocity = &f.reference_velocity_input();
      } else if (t.kind == "posture") {
        auto& f = add(edit.Add<sot::FeaturePosture>(fname, model_, t.joint_name));
        current = [](const sot::Kinematics& k, Eigen::VectorXd* v) { *v = k.q(); };
        feature = &f, reference = &f.reference_input(),
        reference_velocity = &f.reference_velocity_input();
      } else {  // gaze: the point 1 m ahead of the camera is where it looks now
        auto& f = add(edit.Add<sot::FeatureGaze>(fname, model_, t.frame, MaskOf(t, 2)));
        const sot::FrameRef camera = sot::MakeFrameRef(*model_, t.frame, who);
        current = [camera](const sot::Kinematics& k, Eigen::VectorXd* v) {
          *v = k.placement(camera).act(Eigen::Vector3d(0.0, 0.0, 1.0));
        };
        feature = &f, reference = &f.target_input(),
        reference_velocity = &f.target_velocity_input();
      }
      edit.Connect(*sockets_.kinematics, feature->kinematics_input());

      const bool fixed = t.num_reference == value_size;
      Eigen::VectorXd initial(value_size);
      if (fixed) {
        initial = Eigen::Map<const Eigen::VectorXd>(t.reference.data(), value_size);
      } else {
        current(now, &initial);  // a value of the right size until the swap sets the real one
      }
      if (t.reference_channel.rfind(kWalkPrefix, 0) == 0) {  // from the pattern generator
        ConnectWalkReference(t.reference_channel, *built, edit, *reference, *reference_velocity);
      } else if (!t.reference_channel.empty()) {
        auto& stream = add(edit.Add<ReferenceStream>(prefix + t.name + "_reference",
                                                     se3 ? Kind::kSe3 : Kind::kVector, initial,
                                                     derivative_size));
        edit.Connect(se3 ? static_cast<graph::SignalBase&>(*stream.pose_output())
                         : static_cast<graph::SignalBase&>(stream.value_output()),
                     *reference);
        edit.Connect(stream.derivative_output(), *reference_velocity);
        built->streams[t.name] = &stream;
        if (!fixed) {
          auto scratch = std::make_shared<Eigen::VectorXd>(initial);
          built->holds.push_back([current, scratch, s = &stream](const sot::Kinematics& k) {
            current(k, scratch.get());
            s->SetInitial(*scratch);
          });
        }
      } else if (se3) {
        auto* input = static_cast<graph::InputSignal<pinocchio::SE3>*>(reference);
        input->SetValue(VectorToPose(initial));
        if (!fixed) {
          auto scratch = std::make_shared<Eigen::VectorXd>(initial);
          built->holds.push_back([current, scratch, input](const sot::Kinematics& k) {
            current(k, scratch.get());
            input->SetValue(VectorToPose(*scratch));
          });
        }
      } else {
        auto* input = static_cast<graph::InputSignal<Eigen::VectorXd>*>(reference);
        input->SetValue(initial);
        if (!fixed) {
          auto scratch = std::make_shared<Eigen::VectorXd>(initial);
          built->holds.push_back([current, scratch, input](const sot::Kinematics& k) {
            current(k, scratch.get());
            input->SetValue(*scratch);
          });
        }
      }
      auto& task = add(edit.Add<sot::Task>(prefix + t.name, *feature, g));
      by_priority[t.priority].push_back(&task);
      built->task_names.push_back(t.name);
      built->task_errors.push_back(&task.error_norm_output());
    } catch (const std::invalid_argument& e) {  // sot::SotError and ours
      Fail(who, e.what());
    } catch (const graph::GraphError& e) {
      Fail(who, e.what());
    }
  }

  // The joint limits bound every level (solver level 0, its own).
  auto& limits_feature = add(edit.Add<sot::FeaturePosture>(prefix + "joint_limits_feature", model_,
                                                           sot::LimitedJoints(*model_)));
  edit.Connect(*sockets_.kinematics, limits_feature.kinematics_input());
  auto& limits = add(edit.Add<sot::Task>(
      prefix + "joint_limits", limits_feature,
      sot::Gain::Constant(sot::JointLimitsOptions{}.position_gain),
      sot::JointLimitBounds(*model_, limits_feature, sot::JointLimitsOptions{})));
  sot::Solver::Levels levels = {{&limits}};
  if (!held_velocities_.empty()) {
    auto& held_feature = add(edit.Add<sot::FeatureHeldVelocities>(
        prefix + "held_velocities_feature", model_, held_velocities_));
    edit.Connect(*sockets_.kinematics, held_feature.kinematics_input());
    levels[0].push_back(
        &add(edit.Add<sot::Task>(prefix + "held_velocities", held_feature, sot::Gain::Constant(1.0),
                                 sot::HeldVelocityBounds(held_feature))));
  }
  for (auto& [priority, tasks] : by_priority) levels.push_back(tasks);

  auto& solver = add(edit.Add<sot::Solver>(prefix + "solver", model_->nv, levels));
  edit.Connect(solver.velocity_output(), *sockets_.command);
  edit.Connect(*sockets_.applied_velocity, solver.initial_velocity_input());
  built->velocity = &solver.velocity_output();
  built->unblended_velocity = &solver.unblended_velocity_output();
  try {
    edit.Prepare();
  } catch (const graph::GraphError& e) {
    Fail(where, e.what());
  }
  return built;
}

}  // namespace marionette::controller
