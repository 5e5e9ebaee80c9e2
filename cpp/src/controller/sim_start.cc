// How a simulated run starts (sim_start.h): what marionette-controller's Impl::Impl did inline.
#include "marionette/controller/sim_start.h"

#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <optional>
#include <stdexcept>

namespace marionette::controller {

Eigen::VectorXd ReferencePosture(const pinocchio::Model& model, const RobotInfo& robot) {
  if (model.referenceConfigurations.count(robot.reference) == 0) {
    throw std::runtime_error(robot.srdf + " has no group_state '" + robot.reference + "'");
  }
  Eigen::VectorXd q0 = model.referenceConfigurations.at(robot.reference);
  for (const GripperInfo& g : robot.grippers) {  // just inside the limit, as marionette.robots
    if (model.existJointName(g.joint))
      q0[model.joints[model.getJointId(g.joint)].idx_q()] = g.open_position;
  }
  return q0;
}

StartedScene StartScene(const std::string& mjcf_path, const pinocchio::Model& model,
                        const RobotInfo& robot, const Eigen::VectorXd& reference,
                        const std::vector<std::pair<std::string, double>>& encoder_offsets) {
  StartedScene out;
  out.q0 = reference;
  try {
    out.scene = std::make_unique<sim::MujocoScene>(mjcf_path, model);
    out.scene->SetEncoderOffsets(encoder_offsets);
  } catch (const std::exception& e) {
    throw std::runtime_error(e.what());
  }
  sim::MujocoScene& scene = *out.scene;
  mjData& d = scene.mutable_data();
  if (scene.model().nkey > 0) {
    mj_resetDataKeyframe(&scene.model(), &d, 0);
    mj_forward(&scene.model(), &d);
    Eigen::VectorXd v(model.nv);
    scene.ReadRobotState(out.q0, v);
  } else {
    Eigen::VectorXd qs(model.nq), vs(model.nv);
    scene.ReadRobotState(qs, vs);
    if (robot.base != "fixed") {
      const int base_nq = robot.base == "free_flyer" ? 7 : 4;
      out.q0.head(base_nq) = qs.head(base_nq);
    }
    scene.WriteRobotState(out.q0, Eigen::VectorXd::Zero(model.nv));
  }
  const mjModel& m = scene.model();
  for (int b = 1; b < m.nbody; ++b) {
    const int jnt = m.body_jntadr[b];
    if (jnt >= 0 && m.jnt_type[jnt] == mjJNT_FREE && m.body_rootid[b] == b &&
        std::string(mj_id2name(&m, mjOBJ_BODY, b)) != "base_link") {
      out.free_objects.push_back(mj_id2name(&m, mjOBJ_BODY, b));
      out.free_object_ids.push_back(b);
    }
  }
  for (int s = 0; s < m.nsensor; ++s) {
    if (m.sensor_type[s] != mjSENS_RANGEFINDER) continue;
    const char* name = mj_id2name(&m, mjOBJ_SENSOR, s);
    out.range_finders.names.push_back(name ? name : "rangefinder_" + std::to_string(s));
    out.range_finders.adr.push_back(m.sensor_adr[s]);
    out.range_finders.noise.push_back(m.sensor_noise[s]);
  }
  if (!out.range_finders.empty() && (m.opt.disableflags & mjDSBL_SENSOR)) {
    throw std::runtime_error(mjcf_path + " has rangefinder sensors but disables sensors");
  }
  if (out.range_finders.size() > static_cast<size_t>(kMaxRangeFinders)) {
    throw std::runtime_error(mjcf_path + " has " + std::to_string(out.range_finders.size()) +
                             " rangefinder sensors; RANGE_FINDERS carries at most " +
                             std::to_string(kMaxRangeFinders));
  }
  return out;
}

void ReadRangeFinders(const RangeFinderSet& range_finders, const mjData& d, std::mt19937_64* rng,
                      std::vector<double>* distances) {
  for (size_t i = 0; i < range_finders.size(); ++i) {
    const double r = d.sensordata[range_finders.adr[i]];
    const double sigma = range_finders.noise[i];
    (*distances)[i] = r >= 0.0 && sigma > 0.0
                          ? std::max(0.0, r + std::normal_distribution<double>(0.0, sigma)(*rng))
                          : r;
  }
}

lcmt_range_finders RangeFinderReadings(const std::string& robot_name,
                                       const std::vector<std::string>& names,
                                       const std::vector<double>& distances, int64_t utime) {
  lcmt_range_finders out{};
  out.utime = utime;
  out.robot_name = robot_name;
  out.num_sensors = static_cast<int32_t>(names.size());
  out.name = names;
  out.distance = distances;
  return out;
}

lcmt_object_poses SimulatorObjectPoses(const std::vector<std::string>& names,
                                       const std::vector<double>& poses, int64_t utime) {
  lcmt_object_poses out{};
  out.utime = utime;
  out.camera_name = "simulator";
  out.num_objects = static_cast<int32_t>(names.size());
  for (size_t i = 0; i < names.size(); ++i) {
    lcmt_object_pose p{};
    p.utime = utime;
    p.object_name = names[i];
    for (int k = 0; k < 3; ++k) p.position_world[k] = poses[7 * i + k];
    for (int k = 0; k < 4; ++k) p.quaternion_world[k] = poses[7 * i + 3 + k];
    p.quaternion_camera[0] = 1.0;
    out.objects.push_back(p);
  }
  return out;
}

namespace {

/// The pose of a SIM_COMMAND (position, unit quaternion w x y z), or nullopt when it is not one.
std::optional<pinocchio::SE3> CommandPose(const lcmt_sim_command& msg) {
  const Eigen::Map<const Eigen::Vector3d> p(msg.position);
  const Eigen::Map<const Eigen::Vector4d> wxyz(msg.quaternion);
  if (!p.allFinite() || !wxyz.allFinite() || std::abs(wxyz.norm() - 1.0) > 1e-3) {
    return std::nullopt;
  }
  return pinocchio::SE3(
      Eigen::Quaterniond(wxyz[0], wxyz[1], wxyz[2], wxyz[3]).normalized().toRotationMatrix(), p);
}

/// "slide": a mocap body of the scene (a fixture the scene carries) to a pose over a duration.
std::variant<SimRequest, SimCommandRefusal> ReadSlide(const lcmt_sim_command& msg,
                                                      const sim::MujocoScene& scene) {
  const mjModel& m = scene.model();
  const int body = mj_name2id(&m, mjOBJ_BODY, msg.object_name.c_str());
  if (body <= 0 || m.body_mocapid[body] < 0) {
    std::string known;
    for (int b = 1; b < m.nbody; ++b) {
      if (m.body_mocapid[b] >= 0)
        known += (known.empty() ? "" : ", ") + std::string(mj_id2name(&m, mjOBJ_BODY, b));
    }
    return SimCommandRefusal{"unknown object", "'" + msg.object_name +
                                                   "' is not a mocap body (slide moves those: " +
                                                   (known.empty() ? "none" : known) + ")"};
  }
  const std::optional<pinocchio::SE3> pose = CommandPose(msg);
  if (!pose) {
    return SimCommandRefusal{"invalid pose",
                             "'" + msg.object_name + "': non-finite or non-unit quaternion"};
  }
  if (!std::isfinite(msg.duration) || msg.duration < 0.0) {
    return SimCommandRefusal{"invalid slide",
                             "'" + msg.object_name + "': the duration must be finite and >= 0 s"};
  }
  SimRequest r;
  r.kind = SimRequest::kSlide;
  r.id = body;
  r.pose = *pose;
  r.duration_s = msg.duration;
  return r;
}

}  // namespace

std::variant<SimRequest, SimCommandRefusal> ReadSimCommand(
    const lcmt_sim_command& msg, const sim::MujocoScene& scene,
    const std::vector<std::string>& free_objects, const std::vector<int>& free_object_ids) {
  SimRequest r;
  if (msg.command == "attach" || msg.command == "detach") {
    r.kind = msg.command == "attach" ? SimRequest::kAttach : SimRequest::kDetach;
    try {
      r.id = scene.WeldId(msg.object_name);  // its message lists the scene's welds
    } catch (const sim::SimError& e) {
      return SimCommandRefusal{"unknown weld", e.what()};
    }
    return r;
  }
  if (msg.command == "slide") return ReadSlide(msg, scene);
  if (msg.command != "set_object_pose" && msg.command != "push" && msg.command != "set_friction") {
    return SimCommandRefusal{
        "unknown command",
        "'" + msg.command + "' (set_object_pose, push, set_friction, slide, attach, detach)"};
  }
  const auto it = std::find(free_objects.begin(), free_objects.end(), msg.object_name);
  if (it == free_objects.end()) {
    std::string known;
    for (const std::string& n : free_objects) known += (known.empty() ? "" : ", ") + n;
    return SimCommandRefusal{"unknown object", "'" + msg.object_name + "' (free objects: " +
                                                   (known.empty() ? "none" : known) + ")"};
  }
  r.id = free_object_ids[it - free_objects.begin()];
  if (msg.command == "push") {
    const Eigen::Map<const Eigen::Vector3d> f(msg.force);
    if (!f.allFinite() || !std::isfinite(msg.duration) || msg.duration < 0.0) {
      return SimCommandRefusal{"invalid push",
                               "'" + msg.object_name + "': non-finite force or negative duration"};
    }
    r.kind = SimRequest::kPush;
    r.force = f;
    r.duration_s = msg.duration;
    return r;
  }
  if (msg.command == "set_friction") {
    if (!std::isfinite(msg.friction) || msg.friction < 0.0) {
      return SimCommandRefusal{
          "invalid friction", "'" + msg.object_name + "': the coefficient must be finite and >= 0"};
    }
    r.kind = SimRequest::kFriction;
    r.friction = msg.friction;
    return r;
  }
  const std::optional<pinocchio::SE3> pose = CommandPose(msg);
  if (!pose) {
    return SimCommandRefusal{"invalid pose",
                             "'" + msg.object_name + "': non-finite or non-unit quaternion"};
  }
  r.kind = SimRequest::kMove;
  r.pose = *pose;
  return r;
}

void ApplySimRequest(sim::MujocoScene& scene, const SimRequest& request) {
  switch (request.kind) {
    case SimRequest::kAttach:
    case SimRequest::kDetach:
      scene.SetWeld(request.id, request.kind == SimRequest::kAttach);
      break;
    case SimRequest::kMove:
      scene.MoveFreeBody(request.id, request.pose);
      break;
    case SimRequest::kPush:
      scene.Push(request.id, request.force, request.duration_s);
      break;
    case SimRequest::kFriction:
      scene.SetFriction(request.id, request.friction);
      break;
    case SimRequest::kSlide:
      scene.Slide(request.id, request.pose, request.duration_s);
      break;
  }
}

}  // namespace marionette::controller
