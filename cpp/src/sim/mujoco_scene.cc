#include "marionette/sim/mujoco_scene.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace marionette::sim {
namespace {

int JointId(const mjModel* m, const std::string& name) {
  return mj_name2id(m, mjOBJ_JOINT, name.c_str());
}

Eigen::Matrix3d QuatToMatrix(const double* wxyz) {
  return Eigen::Quaterniond(wxyz[0], wxyz[1], wxyz[2], wxyz[3]).normalized().toRotationMatrix();
}

}  // namespace

MujocoScene::MujocoScene(const std::string& mjcf_path, const pinocchio::Model& robot) {
  char error[1000] = "";
  model_ = mj_loadXML(mjcf_path.c_str(), nullptr, error, sizeof(error));
  if (model_ == nullptr) throw SimError("MuJoCo cannot load '" + mjcf_path + "': " + error);
  data_ = mj_makeData(model_);
  own_contype_.assign(model_->geom_contype, model_->geom_contype + model_->ngeom);
  own_conaffinity_.assign(model_->geom_conaffinity, model_->geom_conaffinity + model_->ngeom);
  open_count_.assign(model_->ngeom, 0);
  nq_ = robot.nq;
  nv_ = robot.nv;

  for (pinocchio::JointIndex j = 1; j < robot.joints.size(); ++j) {
    const std::string& name = robot.names[j];
    const std::string shortname = robot.joints[j].shortname();
    if (shortname == "JointModelFreeFlyer") {
      const int id = JointId(model_, name);
      if (id < 0 || model_->jnt_type[id] != mjJNT_FREE) {
        throw SimError("scene '" + mjcf_path + "' has no free joint '" + name +
                       "' for the robot's free-flyer base");
      }
      base_ = Base::kFreeFlyer;
      base_qpos_ = model_->jnt_qposadr[id];
      base_dof_ = model_->jnt_dofadr[id];
      continue;
    }
    if (shortname == "JointModelPlanar") {
      const char* parts[3] = {"root_x", "root_y", "root_yaw"};
      for (int k = 0; k < 3; ++k) {
        const int id = JointId(model_, parts[k]);
        if (id < 0) {
          throw SimError("scene '" + mjcf_path + "' has no joint '" + parts[k] +
                         "' for the robot's planar base");
        }
        planar_qpos_[k] = model_->jnt_qposadr[id];
        planar_dof_[k] = model_->jnt_dofadr[id];
      }
      base_ = Base::kPlanar;
      continue;
    }
    if (robot.joints[j].nq() != 1 || robot.joints[j].nv() != 1) {
      throw SimError("joint '" + name + "' (" + shortname +
                     ") is not a 1-dof joint; only revolute/prismatic joints map onto MuJoCo");
    }
    const int id = JointId(model_, name);
    if (id < 0) throw SimError("scene '" + mjcf_path + "' has no joint '" + name + "'");
    JointMap map{model_->jnt_qposadr[id],
                 model_->jnt_dofadr[id],
                 robot.joints[j].idx_q(),
                 robot.joints[j].idx_v(),
                 -1,
                 name};
    for (int a = 0; a < model_->nu; ++a) {
      if (model_->actuator_trntype[a] == mjTRN_JOINT && model_->actuator_trnid[2 * a] == id) {
        map.actuator = a;
        actuated_names_.push_back(name);
        break;
      }
    }
    joints_.push_back(map);
  }
  mj_forward(model_, data_);
}

MujocoScene::~MujocoScene() {
  mj_deleteData(data_);
  mj_deleteModel(model_);
}

int MujocoScene::SubstepsFor(double dt) const {
  const double ratio = dt / model_->opt.timestep;
  const int n = static_cast<int>(std::lround(ratio));
  if (n < 1 || std::abs(ratio - n) > 1e-9 * ratio) {
    throw SimError("the control period " + std::to_string(dt) +
                   " s is not a multiple of the MuJoCo timestep " +
                   std::to_string(model_->opt.timestep) + " s");
  }
  return n;
}

void MujocoScene::ReadRobotState(Eigen::Ref<Eigen::VectorXd> q,
                                 Eigen::Ref<Eigen::VectorXd> v) const {
  const double* qpos = data_->qpos;
  const double* qvel = data_->qvel;
  if (base_ == Base::kFreeFlyer) {
    const double* p = qpos + base_qpos_;
    const Eigen::Matrix3d R_WB = QuatToMatrix(p + 3);
    q.head<3>() = Eigen::Map<const Eigen::Vector3d>(p);
    q.segment<4>(3) << p[4], p[5], p[6], p[3];  // wxyz -> xyzw
    const double* dv = qvel + base_dof_;
    v.head<3>() = R_WB.transpose() * Eigen::Map<const Eigen::Vector3d>(dv);  // world -> base
    v.segment<3>(3) = Eigen::Map<const Eigen::Vector3d>(dv + 3);             // already in base
  } else if (base_ == Base::kPlanar) {
    const double yaw = qpos[planar_qpos_[2]];
    const double c = std::cos(yaw), s = std::sin(yaw);
    q.head<4>() << qpos[planar_qpos_[0]], qpos[planar_qpos_[1]], c, s;
    const double vx = qvel[planar_dof_[0]], vy = qvel[planar_dof_[1]];
    v.head<3>() << c * vx + s * vy, -s * vx + c * vy, qvel[planar_dof_[2]];
  }
  for (const JointMap& j : joints_) {
    q[j.idx_q] = qpos[j.qpos_adr] - j.encoder_offset;
    v[j.idx_v] = qvel[j.dof_adr];
  }
}

void MujocoScene::WriteRobotState(const Eigen::VectorXd& q, const Eigen::VectorXd& v) {
  if (q.size() != nq_ || v.size() != nv_) {
    throw SimError("WriteRobotState: q has " + std::to_string(q.size()) + " entries (expected " +
                   std::to_string(nq_) + "), v " + std::to_string(v.size()) + " (expected " +
                   std::to_string(nv_) + ")");
  }
  double* qpos = data_->qpos;
  double* qvel = data_->qvel;
  if (base_ == Base::kFreeFlyer) {
    double* p = qpos + base_qpos_;
    const Eigen::Quaterniond quat(q[6], q[3], q[4], q[5]);
    p[0] = q[0], p[1] = q[1], p[2] = q[2];
    p[3] = quat.w(), p[4] = quat.x(), p[5] = quat.y(), p[6] = quat.z();
    const Eigen::Vector3d v_world = quat.normalized().toRotationMatrix() * v.head<3>();
    for (int k = 0; k < 3; ++k) {
      qvel[base_dof_ + k] = v_world[k];
      qvel[base_dof_ + 3 + k] = v[3 + k];
    }
  } else if (base_ == Base::kPlanar) {
    const double yaw = std::atan2(q[3], q[2]);
    const double c = std::cos(yaw), s = std::sin(yaw);
    qpos[planar_qpos_[0]] = q[0];
    qpos[planar_qpos_[1]] = q[1];
    qpos[planar_qpos_[2]] = yaw;
    qvel[planar_dof_[0]] = c * v[0] - s * v[1];
    qvel[planar_dof_[1]] = s * v[0] + c * v[1];
    qvel[planar_dof_[2]] = v[2];
  }
  for (const JointMap& j : joints_) {
    qpos[j.qpos_adr] = q[j.idx_q] + j.encoder_offset;
    qvel[j.dof_adr] = v[j.idx_v];
  }
  // Joints tied to another by an <equality><joint> (URDF mimics: a parallel gripper's second
  // finger, absent from the controller's model) follow it: q1 - q1_0 = Σ_k a_k (q2 - q2_0)^k, q̇1 =
  // dq1/dq2 q̇2.
  for (int e = 0; e < model_->neq; ++e) {
    if (model_->eq_type[e] != mjEQ_JOINT || model_->eq_obj2id[e] < 0) continue;
    const int j1 = model_->eq_obj1id[e], j2 = model_->eq_obj2id[e];
    const int a1 = model_->jnt_qposadr[j1], a2 = model_->jnt_qposadr[j2];
    const double* c = model_->eq_data + e * mjNEQDATA;
    const double x = qpos[a2] - model_->qpos0[a2];
    double y = 0.0, dy = 0.0;
    for (int k = 4; k >= 0; --k) y = y * x + c[k];
    for (int k = 4; k >= 1; --k) dy = dy * x + k * c[k];
    qpos[a1] = model_->qpos0[a1] + y;
    qvel[model_->jnt_dofadr[j1]] = dy * qvel[model_->jnt_dofadr[j2]];
  }
  mj_forward(model_, data_);
}

void MujocoScene::ReadJointEfforts(Eigen::Ref<Eigen::VectorXd> effort_v) const {
  effort_v.setZero();
  for (const JointMap& j : joints_) {
    if (j.actuator >= 0) effort_v[j.idx_v] = data_->actuator_force[j.actuator];
  }
}

void MujocoScene::WriteServoTargets(const Eigen::VectorXd& q_des, const Eigen::VectorXd& v_des) {
  for (const JointMap& j : joints_) {
    if (j.actuator < 0) continue;
    const double kp = model_->actuator_gainprm[j.actuator * mjNGAIN];
    const double kv = -model_->actuator_biasprm[j.actuator * mjNBIAS + 2];
    data_->ctrl[j.actuator] =
        q_des[j.idx_q] + j.encoder_offset + (kp > 0.0 ? kv / kp : 0.0) * v_des[j.idx_v];
  }
}

void MujocoScene::SetEncoderOffsets(const std::vector<std::pair<std::string, double>>& offsets) {
  std::vector<double> by_joint(joints_.size(), 0.0);
  for (const auto& [name, offset] : offsets) {
    size_t k = 0;
    while (k < joints_.size() && joints_[k].name != name) ++k;
    if (k == joints_.size())
      throw SimError("encoder offset for '" + name + "': the robot has no such 1-dof joint");
    if (!std::isfinite(offset)) throw SimError("encoder offset for '" + name + "' is not finite");
    by_joint[k] = offset;
  }
  for (size_t k = 0; k < joints_.size(); ++k) joints_[k].encoder_offset = by_joint[k];
}

void MujocoScene::Step1() {
  for (int i = 0; i < num_pushes_; ++i) {  // external forces act from mj_step2 on
    Eigen::Map<Eigen::Vector3d>(data_->xfrc_applied + 6 * pushes_[i].body) = pushes_[i].force;
  }
  mj_step1(model_, data_);
}

void MujocoScene::Step2(int substeps) {
  mj_step2(model_, data_);
  for (int i = 1; i < substeps; ++i) mj_step(model_, data_);
  if (!releases_.empty()) EndClearReleases();
  // Pushes end after the steps that covered their duration (the control period's resolution).
  const double elapsed = substeps * model_->opt.timestep;
  for (int i = 0; i < num_pushes_;) {
    pushes_[i].remaining_s -= elapsed;
    if (pushes_[i].remaining_s > 1e-12) {
      ++i;
      continue;
    }
    Eigen::Map<Eigen::Vector3d>(data_->xfrc_applied + 6 * pushes_[i].body).setZero();
    pushes_[i] = pushes_[--num_pushes_];
  }
  if (num_slides_ > 0) AdvanceSlides(elapsed);
}

void MujocoScene::AdvanceSlides(double elapsed_s) {
  for (int i = 0; i < num_slides_;) {
    ActiveSlide& a = slides_[i];
    a.elapsed_s += elapsed_s;
    const double s = a.duration_s > 0.0 ? std::min(1.0, a.elapsed_s / a.duration_s) : 1.0;
    const Eigen::Vector3d p = a.from_p + s * (a.to_p - a.from_p);
    const Eigen::Quaterniond q = a.from_q.slerp(s, a.to_q);
    for (int k = 0; k < 3; ++k) data_->mocap_pos[3 * a.mocap + k] = p[k];
    data_->mocap_quat[4 * a.mocap] = q.w();
    data_->mocap_quat[4 * a.mocap + 1] = q.x();
    data_->mocap_quat[4 * a.mocap + 2] = q.y();
    data_->mocap_quat[4 * a.mocap + 3] = q.z();
    if (s < 1.0) {
      ++i;
      continue;
    }
    slides_[i] = slides_[--num_slides_];
  }
}

void MujocoScene::Slide(int body_id, const pinocchio::SE3& X_WB, double duration_s) {
  if (body_id <= 0 || body_id >= model_->nbody || model_->body_mocapid[body_id] < 0) {
    throw SimError("Slide: body " + std::to_string(body_id) + " is not a mocap body");
  }
  if (!std::isfinite(duration_s) || duration_s < 0.0 || !X_WB.translation().allFinite() ||
      !X_WB.rotation().allFinite()) {
    throw SimError("Slide: the pose must be finite and the duration >= 0 s");
  }
  const int mocap = model_->body_mocapid[body_id];
  int slot = 0;
  while (slot < num_slides_ && slides_[slot].mocap != mocap) ++slot;
  if (slot == num_slides_) {
    if (num_slides_ == kMaxSlides) {
      throw SimError("Slide: " + std::to_string(kMaxSlides) + " bodies slide already");
    }
    ++num_slides_;
  }
  const double* q = data_->mocap_quat + 4 * mocap;
  ActiveSlide& a = slides_[slot];
  a.mocap = mocap;
  a.from_p = Eigen::Map<const Eigen::Vector3d>(data_->mocap_pos + 3 * mocap);
  a.from_q = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized();
  a.to_p = X_WB.translation();
  a.to_q = Eigen::Quaterniond(X_WB.rotation()).normalized();
  if (a.from_q.dot(a.to_q) < 0.0) a.to_q.coeffs() *= -1.0;  // the shorter way round
  a.elapsed_s = 0.0;
  a.duration_s = duration_s;
}

void MujocoScene::Push(int body_id, const Eigen::Vector3d& force_W, double duration_s) {
  if (body_id <= 0 || body_id >= model_->nbody) {
    throw SimError("Push: " + std::to_string(body_id) + " is not a body of the scene");
  }
  if (!force_W.allFinite() || !std::isfinite(duration_s) || duration_s < 0.0) {
    throw SimError("Push: the force must be finite and the duration >= 0 s");
  }
  int slot = 0;
  while (slot < num_pushes_ && pushes_[slot].body != body_id) ++slot;
  if (slot == num_pushes_) {
    if (num_pushes_ == kMaxPushes) {
      throw SimError("Push: " + std::to_string(kMaxPushes) + " bodies are pushed already");
    }
    ++num_pushes_;
  }
  pushes_[slot] = {body_id, force_W, duration_s};
}

void MujocoScene::SetFriction(int body_id, double mu) {
  if (body_id <= 0 || body_id >= model_->nbody) {
    throw SimError("SetFriction: " + std::to_string(body_id) + " is not a body of the scene");
  }
  if (!std::isfinite(mu) || mu < 0.0) {
    throw SimError("SetFriction: the coefficient must be finite and >= 0");
  }
  int top = 0;
  for (int g = 0; g < model_->ngeom; ++g) {
    if (model_->geom_bodyid[g] != body_id) top = std::max(top, model_->geom_priority[g]);
  }
  int changed = 0;
  for (int g = 0; g < model_->ngeom; ++g) {
    if (model_->geom_bodyid[g] != body_id) continue;
    model_->geom_friction[3 * g] = mu;
    model_->geom_priority[g] = top + 1;
    ++changed;
  }
  if (changed == 0) {
    throw SimError("SetFriction: body " + std::to_string(body_id) + " has no geom");
  }
}

int MujocoScene::BodyId(const std::string& body) const {
  const int id = mj_name2id(model_, mjOBJ_BODY, body.c_str());
  if (id < 0) throw SimError("no body '" + body + "' in the MuJoCo scene");
  return id;
}

ContactWrench MujocoScene::BodyContactWrench(const std::string& body) const {
  return BodyContactWrench(BodyId(body));
}

ContactWrench MujocoScene::BodyContactWrench(int id) const {
  const Eigen::Vector3d p_WB = Eigen::Map<const Eigen::Vector3d>(data_->xpos + 3 * id);
  ContactWrench w;
  for (int i = 0; i < data_->ncon; ++i) {
    const mjContact& c = data_->contact[i];
    const int b1 = model_->geom_bodyid[c.geom1];
    const int b2 = model_->geom_bodyid[c.geom2];
    if ((b1 == id) == (b2 == id)) continue;  // not this body, or a self contact
    mjtNum f6[6];
    mj_contactForce(model_, data_, i, f6);
    // c.frame rows: normal (from geom1 to geom2), then the tangents; f6 = force in that frame,
    // the force geom1 exerts on geom2.
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> frame(c.frame);
    Eigen::Vector3d f = frame.transpose() * Eigen::Map<const Eigen::Vector3d>(f6);
    if (b1 == id) f = -f;
    const Eigen::Vector3d r = Eigen::Map<const Eigen::Vector3d>(c.pos) - p_WB;
    w.force += f;
    w.torque += r.cross(f);
  }
  return w;
}

pinocchio::SE3 MujocoScene::BodyPose(const std::string& body) const {
  const int id = BodyId(body);
  return pinocchio::SE3(QuatToMatrix(data_->xquat + 4 * id),
                        Eigen::Map<const Eigen::Vector3d>(data_->xpos + 3 * id));
}

void MujocoScene::SetFreeBodyPose(const std::string& body, const pinocchio::SE3& X_WB) {
  const int id = BodyId(body);
  const int jnt = model_->body_jntadr[id];
  if (jnt < 0 || model_->jnt_type[jnt] != mjJNT_FREE) {
    throw SimError("body '" + body + "' has no free joint: it cannot be moved");
  }
  MoveFreeBody(id, X_WB);
  mj_forward(model_, data_);
}

void MujocoScene::MoveFreeBody(int body_id, const pinocchio::SE3& X_WB) {
  const int jnt = model_->body_jntadr[body_id];
  double* p = data_->qpos + model_->jnt_qposadr[jnt];
  const Eigen::Quaterniond quat(X_WB.rotation());
  for (int k = 0; k < 3; ++k) p[k] = X_WB.translation()[k];
  p[3] = quat.w(), p[4] = quat.x(), p[5] = quat.y(), p[6] = quat.z();
  for (int k = 0; k < 6; ++k) data_->qvel[model_->jnt_dofadr[jnt] + k] = 0.0;
}

int MujocoScene::WeldId(const std::string& name) const {
  const int id = mj_name2id(model_, mjOBJ_EQUALITY, name.c_str());
  if (id >= 0 && model_->eq_type[id] == mjEQ_WELD) return id;
  std::string known;
  for (int i = 0; i < model_->neq; ++i) {
    if (model_->eq_type[i] != mjEQ_WELD) continue;
    const char* n = mj_id2name(model_, mjOBJ_EQUALITY, i);
    known += (known.empty() ? "" : ", ") + std::string(n ? n : "?");
  }
  throw SimError("no weld '" + name + "' in the scene (welds: " + (known.empty() ? "none" : known) +
                 ")");
}

void MujocoScene::SetWeld(int weld_id, bool active) {
  if (weld_id < 0 || weld_id >= model_->neq || model_->eq_type[weld_id] != mjEQ_WELD) {
    throw SimError("SetWeld: " + std::to_string(weld_id) + " is not a weld equality");
  }
  if (active) {
    // MuJoCo 2.2 weld data: anchor (3), then the pose of body2 in body1 (position, quaternion
    // w x y z), then the torque scale. Hold the bodies where they are now.
    const auto pose = [&](int body) {
      return pinocchio::SE3(QuatToMatrix(data_->xquat + 4 * body),
                            Eigen::Map<const Eigen::Vector3d>(data_->xpos + 3 * body));
    };
    const pinocchio::SE3 X_12 =
        pose(model_->eq_obj1id[weld_id]).actInv(pose(model_->eq_obj2id[weld_id]));
    const Eigen::Quaterniond quat(X_12.rotation());
    double* eq = model_->eq_data + mjNEQDATA * weld_id;
    for (int k = 0; k < 3; ++k) eq[3 + k] = X_12.translation()[k];
    eq[6] = quat.w(), eq[7] = quat.x(), eq[8] = quat.y(), eq[9] = quat.z();
  }
  EndReleases(
      [&](const Release& r) { return r.weld == weld_id; });  // taken again, or released twice
  if (!active && model_->eq_active[weld_id] != 0) {
    Release r{weld_id, {}, {}};
    for (int g = 0; g < model_->ngeom; ++g) {
      if (SubtreeOf(model_->geom_bodyid[g], model_->eq_obj1id[weld_id])) {
        r.hand_geoms.push_back(g);
        ++open_count_[g];
        model_->geom_contype[g] = 0;
        model_->geom_conaffinity[g] = 0;
      } else if (model_->geom_bodyid[g] == model_->eq_obj2id[weld_id]) {
        r.object_geoms.push_back(g);
      }
    }
    releases_.push_back(std::move(r));
  }
  model_->eq_active[weld_id] = active ? 1 : 0;
}

bool MujocoScene::SubtreeOf(int body, int root) const {
  for (; body > 0; body = model_->body_parentid[body]) {
    if (body == root) return true;
  }
  return root == 0;
}

void MujocoScene::EndReleases(const std::function<bool(const Release&)>& ended) {
  size_t kept = 0;  // compacted in place: no allocation on the loop's tick
  for (size_t k = 0; k < releases_.size(); ++k) {
    Release& r = releases_[k];
    if (!ended(r)) {
      if (kept != k) releases_[kept] = std::move(r);
      ++kept;
      continue;
    }
    for (int g : r.hand_geoms) {  // collides again unless another release holds it open
      if (--open_count_[g] > 0) continue;
      model_->geom_contype[g] = own_contype_[g];
      model_->geom_conaffinity[g] = own_conaffinity_[g];
    }
  }
  releases_.resize(kept);
}

void MujocoScene::EndClearReleases() {
  constexpr double kMargin = 0.005;  // [m] beyond touching bounding spheres
  const auto clear = [&](const Release& r) {
    for (int h : r.hand_geoms) {
      for (int o : r.object_geoms) {
        const Eigen::Map<const Eigen::Vector3d> ph(data_->geom_xpos + 3 * h),
            po(data_->geom_xpos + 3 * o);
        if ((ph - po).norm() < model_->geom_rbound[h] + model_->geom_rbound[o] + kMargin)
          return false;
      }
    }
    return true;
  };
  EndReleases(clear);
}

}  // namespace marionette::sim
