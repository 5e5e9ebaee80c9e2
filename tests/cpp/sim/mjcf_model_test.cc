// The generated MJCF models (models/, scripts/generate_models.py) against Pinocchio's models of
// the same URDFs: MuJoCo 2.2.2 loads every robot, object and scene file; joint names and order
// agree; at random configurations within the limits every MuJoCo body sits where Pinocchio puts
// the frame of the link of the same name (1e-6); masses and centres of mass agree; servos,
// cameras, soles and keyframes follow the conventions of models/README.md.
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <filesystem>

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>
#include "marionette/controller/robots.h"

#include <Eigen/Geometry>
#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>
#include <pinocchio/parsers/urdf.hpp>

#include <cmath>
#include <fstream>
#include <iterator>
#include <memory>
#include <random>
#include <string>
#include <vector>

namespace {

namespace pin = pinocchio;

const std::string kModels = MARIONETTE_MODELS_DIR;

enum class Base { kFreeFlyer, kPlanar, kFixed };

struct RobotCase {
  std::string name;
  Base base;
  std::string camera;         ///< "" if none
  std::string camera_frame;   ///< "" if none
  bool moving_mimics = true;  ///< robot.yaml simulation/moving_mimics
  int urdf_mimics = 0;        ///< joints with a <mimic> in the URDF
};

std::ostream& operator<<(std::ostream& os, const RobotCase& c) { return os << c.name; }

// Every robot of models/ (robot.yaml read by the controller's loader).
RobotCase Robot(const std::string& name) {
  const marionette::controller::RobotInfo r = marionette::controller::FindRobot(name, kModels);
  const Base base = r.base == "free_flyer" ? Base::kFreeFlyer
                    : r.base == "planar"   ? Base::kPlanar
                                           : Base::kFixed;
  const YAML::Node sim = YAML::LoadFile(r.directory + "/robot.yaml")["simulation"];
  const bool moving = !(sim && sim["moving_mimics"]) || sim["moving_mimics"].as<bool>();
  std::ifstream urdf(r.urdf);
  const std::string text((std::istreambuf_iterator<char>(urdf)), std::istreambuf_iterator<char>());
  int mimics = 0;  // <mimic joint=...> elements, not <transmission>'s <mimicJoint> (TALOS')
  for (size_t at = text.find("<mimic "); at != std::string::npos;
       at = text.find("<mimic ", at + 1)) {
    ++mimics;
  }
  return {r.name, base, r.camera, r.camera_frame, moving, mimics};
}

std::vector<RobotCase> AllRobots() {
  std::vector<RobotCase> out;
  for (const std::string& name : marionette::controller::RobotNames(kModels)) {
    out.push_back(Robot(name));
  }
  return out;
}

const std::vector<RobotCase> kRobots = AllRobots();

struct MjModelDeleter {
  void operator()(mjModel* m) const { mj_deleteModel(m); }
};
struct MjDataDeleter {
  void operator()(mjData* d) const { mj_deleteData(d); }
};
using MjModelPtr = std::unique_ptr<mjModel, MjModelDeleter>;
using MjDataPtr = std::unique_ptr<mjData, MjDataDeleter>;

MjModelPtr LoadMjcf(const std::string& path) {
  char error[1000] = "";
  MjModelPtr m(mj_loadXML(path.c_str(), nullptr, error, sizeof(error)));
  EXPECT_NE(m, nullptr) << path << ": " << error;
  return m;
}

pin::Model LoadPinocchio(const RobotCase& c) {
  pin::Model model;
  const std::string urdf = kModels + "/" + c.name + "/" + c.name + ".urdf";
  switch (c.base) {
    case Base::kFreeFlyer:
      pin::urdf::buildModel(urdf, pin::JointModelFreeFlyer(), model);
      break;
    case Base::kPlanar:
      pin::urdf::buildModel(urdf, pin::JointModelPlanar(), model);
      break;
    case Base::kFixed:
      pin::urdf::buildModel(urdf, model);
      break;
  }
  return model;
}

// MuJoCo joint names of Pinocchio's joints, in order (models/README.md, "Base joints").
std::vector<std::string> ExpectedMujocoJoints(const pin::Model& model, Base base) {
  std::vector<std::string> names;
  for (pin::JointIndex j = 1; j < static_cast<pin::JointIndex>(model.njoints); ++j) {
    if (j == 1 && base == Base::kPlanar) {
      names.insert(names.end(), {"root_x", "root_y", "root_yaw"});
    } else {
      names.push_back(model.names[j]);
    }
  }
  return names;
}

// Random Pinocchio configuration (nq): joints uniform within their limits, base anywhere
// within a few metres, any orientation.
Eigen::VectorXd RandomConfiguration(const pin::Model& model, Base base, std::mt19937* rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Eigen::VectorXd q(model.nq);
  for (int i = 0; i < model.nq; ++i) {
    // Pinocchio bounds unbounded coordinates (free-flyer and planar translations) by
    // +/- max double: draw those within +/- 2 m.
    const double lo = model.lowerPositionLimit[i], hi = model.upperPositionLimit[i];
    q[i] = (std::abs(lo) < 1e10 && std::abs(hi) < 1e10) ? lo + unit(*rng) * (hi - lo)
                                                        : -2.0 + 4.0 * unit(*rng);
  }
  if (base == Base::kFreeFlyer) {
    std::normal_distribution<double> normal;
    Eigen::Vector4d v(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
    q.segment<4>(3) = v.normalized();  // x y z w
  } else if (base == Base::kPlanar) {
    const double yaw = -M_PI + 2 * M_PI * unit(*rng);
    q[2] = std::cos(yaw);
    q[3] = std::sin(yaw);
  }
  return q;
}

// True when joint j of m follows another joint through an <equality><joint> (a URDF mimic
// joint that Pinocchio keeps fixed: the UR10 gripper's right finger). Such joints are MuJoCo-only.
bool IsMimic(const mjModel* m, int j) {
  for (int e = 0; e < m->neq; ++e) {
    if (m->eq_type[e] == mjEQ_JOINT && m->eq_obj1id[e] == j && m->eq_obj2id[e] >= 0) return true;
  }
  return false;
}

int CountMimics(const mjModel* m) {
  int n = 0;
  for (int j = 0; j < m->njnt; ++j) n += IsMimic(m, j);
  return n;
}

// MuJoCo qpos (robot first in the model) from Pinocchio q: free joint quaternion w x y z,
// planar base as x, y, yaw; 1-dof joints by name (mimic joints keep their qpos, 0: where
// Pinocchio's fixed joints put their links).
void PinocchioToMujoco(const mjModel* m, const pin::Model& model, const Eigen::VectorXd& q,
                       Base base, mjtNum* qpos) {
  if (base == Base::kFreeFlyer) {
    for (int i = 0; i < 3; ++i) qpos[i] = q[i];
    qpos[3] = q[6];
    qpos[4] = q[3];
    qpos[5] = q[4];
    qpos[6] = q[5];
  } else if (base == Base::kPlanar) {
    qpos[0] = q[0];
    qpos[1] = q[1];
    qpos[2] = std::atan2(q[3], q[2]);
  }
  for (pin::JointIndex j = base == Base::kFixed ? 1 : 2; j < model.joints.size(); ++j) {
    const int id = mj_name2id(m, mjOBJ_JOINT, model.names[j].c_str());
    ASSERT_GE(id, 0) << model.names[j];
    qpos[m->jnt_qposadr[id]] = q[model.joints[j].idx_q()];
  }
}

Eigen::VectorXd MujocoToPinocchio(const mjModel* m, const pin::Model& model, const mjtNum* qpos,
                                  Base base) {
  Eigen::VectorXd q(model.nq);
  if (base == Base::kFreeFlyer) {
    for (int i = 0; i < 3; ++i) q[i] = qpos[i];
    q[3] = qpos[4];
    q[4] = qpos[5];
    q[5] = qpos[6];
    q[6] = qpos[3];
  } else if (base == Base::kPlanar) {
    q[0] = qpos[0];
    q[1] = qpos[1];
    q[2] = std::cos(qpos[2]);
    q[3] = std::sin(qpos[2]);
  }
  for (pin::JointIndex j = base == Base::kFixed ? 1 : 2; j < model.joints.size(); ++j) {
    const int id = mj_name2id(m, mjOBJ_JOINT, model.names[j].c_str());
    q[model.joints[j].idx_q()] = id < 0 ? std::nan("") : qpos[m->jnt_qposadr[id]];
  }
  return q;
}

Eigen::Matrix3d BodyRotation(const mjData* d, int b) {
  return Eigen::Map<const Eigen::Matrix<mjtNum, 3, 3, Eigen::RowMajor>>(d->xmat + 9 * b);
}

// Largest position and rotation (angle) error over the bodies of the robot, with the robot's
// base placed at X_WB in the MuJoCo world.
struct PoseErrors {
  double position = 0.0;
  double rotation = 0.0;
  int compared = 0;
};

// True when a mimic joint (MuJoCo-only) lies between body b and the world.
bool BelowMimic(const mjModel* m, int b) {
  for (; b > 0; b = m->body_parentid[b]) {
    for (int k = 0; k < m->body_jntnum[b]; ++k) {
      if (IsMimic(m, m->body_jntadr[b] + k)) return true;
    }
  }
  return false;
}

// With `skip_mimic`, bodies moved by mimic joints are left out (where their qpos is not 0:
// Pinocchio keeps them fixed at 0).
// The URDF link of a MuJoCo body: its name, except a root link named "world", whose body is
// "<robot>_world" (MuJoCo reserves "world").
std::string LinkOfBody(const mjModel* m, int b, const pin::Model& model) {
  const char* name = mj_id2name(m, mjOBJ_BODY, b);
  if (name == nullptr) return "";
  const std::string s(name);
  if (!model.existBodyName(s) && s == model.name + "_world" && model.existBodyName("world")) {
    return "world";
  }
  return s;
}

// The MuJoCo body of a URDF link (the inverse of LinkOfBody).
int BodyOfLink(const mjModel* m, const pin::Model& model, const std::string& link) {
  const int b = mj_name2id(m, mjOBJ_BODY, link.c_str());
  if (b >= 0 || link != "world") return b;
  return mj_name2id(m, mjOBJ_BODY, (model.name + "_world").c_str());
}

PoseErrors CompareBodies(const mjModel* m, const mjData* d, const pin::Model& model,
                         const pin::Data& data, const pin::SE3& X_WB, bool skip_mimic = false) {
  PoseErrors e;
  for (int b = 1; b < m->nbody; ++b) {
    const std::string name = LinkOfBody(m, b, model);
    if (name.empty() || !model.existBodyName(name)) continue;
    if (skip_mimic && BelowMimic(m, b)) continue;
    const pin::SE3 X_WF = X_WB * data.oMf[model.getBodyId(name)];
    const Eigen::Vector3d p(d->xpos[3 * b], d->xpos[3 * b + 1], d->xpos[3 * b + 2]);
    const double dp = (p - X_WF.translation()).norm();
    const Eigen::AngleAxisd diff(BodyRotation(d, b).transpose() * X_WF.rotation());
    const double dr = std::abs(diff.angle());
    // A NaN (or infinite) error must fail the comparison, not vanish in std::max.
    e.position = std::isfinite(dp) ? std::max(e.position, dp) : INFINITY;
    e.rotation = std::isfinite(dr) ? std::max(e.rotation, dr) : INFINITY;
    ++e.compared;
  }
  return e;
}

class RobotMjcfTest : public ::testing::TestWithParam<RobotCase> {
 protected:
  void SetUp() override {
    m_ = LoadMjcf(kModels + "/" + GetParam().name + "/" + GetParam().name + ".xml");
    ASSERT_NE(m_, nullptr);
    d_.reset(mj_makeData(m_.get()));
    model_ = LoadPinocchio(GetParam());
    data_ = pin::Data(model_);
  }

  MjModelPtr m_;
  MjDataPtr d_;
  pin::Model model_;
  pin::Data data_{pin::Model()};
};

TEST_P(RobotMjcfTest, JointNamesAndOrderMatchPinocchio) {
  const std::vector<std::string> expected = ExpectedMujocoJoints(model_, GetParam().base);
  std::vector<std::string> joints;  // MuJoCo's, mimic joints aside (MuJoCo-only, 1 dof each)
  for (int j = 0; j < m_->njnt; ++j) {
    if (!IsMimic(m_.get(), j)) joints.push_back(mj_id2name(m_.get(), mjOBJ_JOINT, j));
  }
  EXPECT_EQ(joints, expected);
  const int base_nq = GetParam().base == Base::kPlanar ? -1 : 0;  // planar: 4 (Pinocchio) vs 3
  const int mimics = CountMimics(m_.get());
  EXPECT_EQ(mimics, GetParam().moving_mimics ? GetParam().urdf_mimics : 0)
      << "the URDF's mimic joints move in MuJoCo unless robot.yaml keeps them fixed";
  EXPECT_EQ(m_->nq, model_.nq + base_nq + mimics);
  EXPECT_EQ(m_->nv, model_.nv + mimics);
}

TEST_P(RobotMjcfTest, EveryBodyPoseMatchesPinocchioFrameAtRandomConfigurations) {
  std::mt19937 rng(42);
  for (int trial = 0; trial < 8; ++trial) {
    const Eigen::VectorXd q = RandomConfiguration(model_, GetParam().base, &rng);
    PinocchioToMujoco(m_.get(), model_, q, GetParam().base, d_->qpos);
    mj_kinematics(m_.get(), d_.get());
    pin::framesForwardKinematics(model_, data_, q);
    const PoseErrors e = CompareBodies(m_.get(), d_.get(), model_, data_, pin::SE3::Identity());
    EXPECT_EQ(e.compared, m_->nbody - 1) << "every MuJoCo body is a URDF link";
    EXPECT_LT(e.position, 1e-6) << "trial " << trial;
    EXPECT_LT(e.rotation, 1e-6) << "trial " << trial;
  }
}

TEST_P(RobotMjcfTest, MassAndCentreOfMassMatchPinocchio) {
  // Total mass; Pinocchio keeps the links fixed to the world (UR10's stand) on joint 0.
  double mass = 0.0, pin_mass = 0.0;
  for (int b = 1; b < m_->nbody; ++b) mass += m_->body_mass[b];
  for (const auto& inertia : model_.inertias) pin_mass += inertia.mass();
  EXPECT_NEAR(mass, pin_mass, 1e-9 * mass);
  EXPECT_NEAR(m_->body_subtreemass[m_->jnt_bodyid[0]], pin::computeTotalMass(model_), 1e-9 * mass);
  std::mt19937 rng(7);
  for (int trial = 0; trial < 5; ++trial) {
    const Eigen::VectorXd q = RandomConfiguration(model_, GetParam().base, &rng);
    PinocchioToMujoco(m_.get(), model_, q, GetParam().base, d_->qpos);
    mj_kinematics(m_.get(), d_.get());
    mj_comPos(m_.get(), d_.get());
    // Centre of mass of the subtree of the first joint (the whole robot for a free or planar
    // base; everything above the stand for UR10): Pinocchio's data.com[1] (expressed in the
    // frame of joint 1), MuJoCo's subtree_com of the body that carries the first joint.
    pin::Data data(model_);
    pin::centerOfMass(model_, data, q);
    const Eigen::Vector3d com_pin = data.oMi[1].act(data.com[1]);
    const int b = m_->jnt_bodyid[0];
    const Eigen::Vector3d com_mj(d_->subtree_com[3 * b], d_->subtree_com[3 * b + 1],
                                 d_->subtree_com[3 * b + 2]);
    EXPECT_LT((com_mj - com_pin).norm(), 1e-9)
        << "trial " << trial << ": MuJoCo " << com_mj.transpose() << ", Pinocchio "
        << com_pin.transpose();
  }
}

TEST_P(RobotMjcfTest, EveryJointHasAServoNamedLikeIt) {
  // The free joint and the mimic joints (tied to their driver by an equality) are passive.
  const int first = GetParam().base == Base::kFreeFlyer ? 1 : 0;
  ASSERT_EQ(m_->nu, m_->njnt - first - CountMimics(m_.get()));
  for (int a = 0, j = first; a < m_->nu; ++a, ++j) {
    while (IsMimic(m_.get(), j)) ++j;
    EXPECT_STREQ(mj_id2name(m_.get(), mjOBJ_ACTUATOR, a), mj_id2name(m_.get(), mjOBJ_JOINT, j));
    EXPECT_EQ(m_->actuator_trnid[2 * a], j);
    // Position servo: tau = kp ctrl - kp q - kv dq.
    EXPECT_EQ(m_->actuator_biastype[a], mjBIAS_AFFINE);
    EXPECT_GT(m_->actuator_gainprm[mjNGAIN * a], 0.0);
    EXPECT_DOUBLE_EQ(m_->actuator_biasprm[mjNBIAS * a + 1], -m_->actuator_gainprm[mjNGAIN * a]);
    EXPECT_LT(m_->actuator_biasprm[mjNBIAS * a + 2], 0.0);
    EXPECT_TRUE(m_->actuator_forcelimited[a]);
    if (m_->jnt_limited[j]) {
      EXPECT_DOUBLE_EQ(m_->actuator_ctrlrange[2 * a], m_->jnt_range[2 * j]);
      EXPECT_DOUBLE_EQ(m_->actuator_ctrlrange[2 * a + 1], m_->jnt_range[2 * j + 1]);
    }
  }
  EXPECT_EQ(m_->opt.integrator, mjINT_IMPLICIT);
  EXPECT_DOUBLE_EQ(m_->opt.timestep, 1e-3);
}

TEST_P(RobotMjcfTest, ReferenceKeyframeIsWithinLimitsAndServosHoldIt) {
  const int key = mj_name2id(m_.get(), mjOBJ_KEY, "reference");
  ASSERT_GE(key, 0);
  const mjtNum* qpos = m_->key_qpos + key * m_->nq;
  const mjtNum* ctrl = m_->key_ctrl + key * m_->nu;
  for (int a = 0; a < m_->nu; ++a) {
    const int j = m_->actuator_trnid[2 * a];
    const double q = qpos[m_->jnt_qposadr[j]];
    EXPECT_DOUBLE_EQ(ctrl[a], q) << mj_id2name(m_.get(), mjOBJ_JOINT, j);
    if (m_->jnt_limited[j]) {
      // Strictly inside: TALOS' half_sitting leaves the grippers on their limit otherwise.
      EXPECT_GT(q, m_->jnt_range[2 * j]) << mj_id2name(m_.get(), mjOBJ_JOINT, j);
      EXPECT_LT(q, m_->jnt_range[2 * j + 1]) << mj_id2name(m_.get(), mjOBJ_JOINT, j);
    }
  }
}

// The URDF's mimic joints (the UR10 gripper's right finger): joint1 = offset + multiplier * joint2
// in the keyframe, read back from the URDF text itself (<mimic joint multiplier offset>).
TEST_P(RobotMjcfTest, MimicJointsFollowTheUrdfMimicInTheKeyframe) {
  std::ifstream in(kModels + "/" + GetParam().name + "/" + GetParam().name + ".urdf");
  const std::string urdf((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const mjtNum* qpos = m_->key_qpos + mj_name2id(m_.get(), mjOBJ_KEY, "reference") * m_->nq;
  int seen = 0;
  for (int e = 0; e < m_->neq; ++e) {
    if (m_->eq_type[e] != mjEQ_JOINT) continue;
    const std::string j1 = mj_id2name(m_.get(), mjOBJ_JOINT, m_->eq_obj1id[e]);
    const std::string j2 = mj_id2name(m_.get(), mjOBJ_JOINT, m_->eq_obj2id[e]);
    const size_t at = urdf.find("<joint name=\"" + j1 + "\"");
    ASSERT_NE(at, std::string::npos) << j1;
    const size_t mimic = urdf.find("<mimic", at);
    ASSERT_LT(mimic, urdf.find("</joint>", at)) << j1 << " has no <mimic> in the URDF";
    // An attribute of the <mimic> element, or `fallback` (URDF: multiplier 1, offset 0).
    const auto attr = [&](const std::string& name, const std::string& fallback) {
      const size_t end = urdf.find('>', mimic);
      const size_t a = urdf.find(" " + name + "=\"", mimic);
      if (a == std::string::npos || a > end) return fallback;
      const size_t v = a + name.size() + 3;
      return urdf.substr(v, urdf.find('"', v) - v);
    };
    EXPECT_EQ(attr("joint", ""), j2);
    const double multiplier = std::stod(attr("multiplier", "1"));
    const double offset = std::stod(attr("offset", "0"));
    EXPECT_DOUBLE_EQ(m_->eq_data[e * mjNEQDATA + 0], offset) << j1;
    EXPECT_DOUBLE_EQ(m_->eq_data[e * mjNEQDATA + 1], multiplier) << j1;
    EXPECT_NEAR(qpos[m_->jnt_qposadr[m_->eq_obj1id[e]]],
                offset + multiplier * qpos[m_->jnt_qposadr[m_->eq_obj2id[e]]], 1e-12)
        << j1;
    ++seen;
  }
  EXPECT_EQ(seen, CountMimics(m_.get()));
}

INSTANTIATE_TEST_SUITE_P(Robots, RobotMjcfTest, ::testing::ValuesIn(kRobots),
                         [](const auto& info) { return info.param.name; });

// A camera on an optical frame (z along the view, y down) looks along its -z with y up:
// R_camera = R_optical * diag(1, -1, -1).
TEST(CameraTest, HeadCamerasLookAlongTheOpticalAxis) {
  int cameras = 0;
  for (const RobotCase& robot : kRobots) {
    if (robot.camera.empty()) continue;
    ++cameras;
    const std::string& frame = robot.camera_frame;
    MjModelPtr m = LoadMjcf(kModels + "/" + robot.name + "/" + robot.name + ".xml");
    ASSERT_NE(m, nullptr);
    MjDataPtr d(mj_makeData(m.get()));
    mj_resetDataKeyframe(m.get(), d.get(), 0);
    mj_kinematics(m.get(), d.get());
    mj_camlight(m.get(), d.get());
    const int cam = mj_name2id(m.get(), mjOBJ_CAMERA, robot.camera.c_str());
    ASSERT_GE(cam, 0) << robot.name;
    const int body = mj_name2id(m.get(), mjOBJ_BODY, frame.c_str());
    ASSERT_GE(body, 0);
    const Eigen::Matrix3d R_cam =
        Eigen::Map<const Eigen::Matrix<mjtNum, 3, 3, Eigen::RowMajor>>(d->cam_xmat + 9 * cam);
    const Eigen::Matrix3d expected =
        BodyRotation(d.get(), body) * Eigen::Vector3d(1, -1, -1).asDiagonal();
    EXPECT_LT((R_cam - expected).norm(), 1e-9) << robot.name;
    const double fovy = m->cam_fovy[cam];
    EXPECT_GE(fovy, 45.0);
    EXPECT_LE(fovy, 49.0);
    EXPECT_EQ(m->vis.global.offwidth, 640);
    EXPECT_EQ(m->vis.global.offheight, 480);
  }
  EXPECT_GE(cameras, 2) << "the bundled humanoid and mobile manipulator have head cameras";
}

// TALOS' sole boxes: 0.205 x 0.122 m under the sole frames, bottom on the floor in half-sitting;
// only the soles touch the floor.
TEST(TalosTest, SoleBoxesRestOnTheFloorInHalfSitting) {
  MjModelPtr m = LoadMjcf(kModels + "/talos/talos.xml");
  ASSERT_NE(m, nullptr);
  MjDataPtr d(mj_makeData(m.get()));
  mj_resetDataKeyframe(m.get(), d.get(), mj_name2id(m.get(), mjOBJ_KEY, "reference"));
  mj_forward(m.get(), d.get());
  const int floor = mj_name2id(m.get(), mjOBJ_GEOM, "floor");
  for (const char* side : {"left_sole", "right_sole"}) {
    const int g = mj_name2id(m.get(), mjOBJ_GEOM, side);
    ASSERT_GE(g, 0);
    EXPECT_NEAR(2 * m->geom_size[3 * g], 0.205, 1e-12);
    EXPECT_NEAR(2 * m->geom_size[3 * g + 1], 0.122, 1e-12);
    const double bottom = d->geom_xpos[3 * g + 2] - m->geom_size[3 * g + 2];
    EXPECT_NEAR(bottom, 0.0, 1e-5) << side;
  }
  ASSERT_GT(d->ncon, 0);
  for (int c = 0; c < d->ncon; ++c) {
    const int other = d->contact[c].geom1 == floor ? d->contact[c].geom2 : d->contact[c].geom1;
    const std::string name = mj_id2name(m.get(), mjOBJ_GEOM, other) ?: "";
    EXPECT_TRUE(name == "left_sole" || name == "right_sole") << "floor touches " << name;
  }
}

// The servos (models/README.md, "Servo gains") hold TALOS up in half-sitting: over 3 s with
// constant ctrl = half_sitting the base settles within a few millimetres and degrees and the feet
// stay where they are (the static deflection of finite-stiffness servos, not a fall).
TEST(TalosTest, ServosHoldHalfSittingStandingForThreeSeconds) {
  MjModelPtr m = LoadMjcf(kModels + "/talos/talos.xml");
  ASSERT_NE(m, nullptr);
  MjDataPtr d(mj_makeData(m.get()));
  mj_resetDataKeyframe(m.get(), d.get(), mj_name2id(m.get(), mjOBJ_KEY, "reference"));
  mj_forward(m.get(), d.get());
  const Eigen::Vector3d base0(d->qpos[0], d->qpos[1], d->qpos[2]);
  std::vector<Eigen::Vector3d> soles0;
  const std::vector<int> soles = {mj_name2id(m.get(), mjOBJ_BODY, "left_sole_link"),
                                  mj_name2id(m.get(), mjOBJ_BODY, "right_sole_link")};
  for (int b : soles) soles0.emplace_back(d->xpos[3 * b], d->xpos[3 * b + 1], d->xpos[3 * b + 2]);
  double max_tilt = 0.0;
  for (int i = 0; i < 3000; ++i) {
    mj_step(m.get(), d.get());
    // Tilt of the base: angle between its z axis and the vertical.
    const double tilt = std::acos(std::min(1.0, d->xmat[9 * 1 + 8]));
    max_tilt = std::max(max_tilt, tilt);
  }
  const Eigen::Vector3d base(d->qpos[0], d->qpos[1], d->qpos[2]);
  EXPECT_LT((base - base0).norm(), 5e-3);
  EXPECT_LT(max_tilt, 0.5 * M_PI / 180.0);
  for (size_t k = 0; k < soles.size(); ++k) {
    const Eigen::Vector3d p(d->xpos[3 * soles[k]], d->xpos[3 * soles[k] + 1],
                            d->xpos[3 * soles[k] + 2]);
    EXPECT_LT((p - soles0[k]).norm(), 1e-3) << "sole " << k;
  }
  EXPECT_EQ(d->ncon, 8) << "both sole boxes flat on the floor (4 corners each)";
}

// Scenes: each loads, its keyframe puts the robot at its reference posture (checked against
// Pinocchio) and every object where the scene says.
struct SceneCase {
  std::string scene;
  RobotCase robot;
};

std::ostream& operator<<(std::ostream& os, const SceneCase& c) { return os << c.scene; }

class SceneTest : public ::testing::TestWithParam<SceneCase> {};

TEST_P(SceneTest, LoadsAndPlacesTheRobotAsPinocchio) {
  const SceneCase& c = GetParam();
  MjModelPtr m = LoadMjcf(kModels + "/scenes/" + c.scene + ".xml");
  ASSERT_NE(m, nullptr);
  MjDataPtr d(mj_makeData(m.get()));
  const int key = mj_name2id(m.get(), mjOBJ_KEY, "reference");
  ASSERT_GE(key, 0);
  mj_resetDataKeyframe(m.get(), d.get(), key);
  mj_forward(m.get(), d.get());
  const pin::Model model = LoadPinocchio(c.robot);
  pin::Data data(model);
  const Eigen::VectorXd q = MujocoToPinocchio(m.get(), model, d->qpos, c.robot.base);
  pin::framesForwardKinematics(model, data, q);
  // Fixed bases: the robot's root body placement in the scene.
  pin::SE3 X_WB = pin::SE3::Identity();
  if (c.robot.base == Base::kFixed) {
    const int root = BodyOfLink(m.get(), model, model.frames[1].name);
    ASSERT_GE(root, 0);
    X_WB =
        pin::SE3(BodyRotation(d.get(), root),
                 Eigen::Vector3d(d->xpos[3 * root], d->xpos[3 * root + 1], d->xpos[3 * root + 2])) *
        data.oMf[1].inverse();
  }
  // Bodies moved by mimic joints (MuJoCo only) are left out: Pinocchio keeps them where the URDF
  // fixes them (MimicJointsFollowTheUrdfMimicInTheKeyframe checks those).
  const PoseErrors e = CompareBodies(m.get(), d.get(), model, data, X_WB, /*skip_mimic=*/true);
  // Not hollow: at least the child body of every joint of the robot was compared (a 6-DoF arm
  // with a two-finger hand has 10 bodies, a humanoid dozens).
  EXPECT_GE(e.compared, model.njoints - 1);
  EXPECT_LT(e.position, 1e-6);
  EXPECT_LT(e.rotation, 1e-6);
  // At rest: nothing of the robot penetrates anything by more than 1 mm.
  for (int i = 0; i < d->ncon; ++i) EXPECT_GT(d->contact[i].dist, -1e-3) << c.scene;
}

// Free objects (plank, ball, box) start at rest on their supports: half a second of simulation,
// the robot holding its reference posture, moves none of them by more than 2 mm.
TEST_P(SceneTest, FreeObjectsRestOnTheirSupports) {
  MjModelPtr m = LoadMjcf(kModels + "/scenes/" + GetParam().scene + ".xml");
  ASSERT_NE(m, nullptr);
  MjDataPtr d(mj_makeData(m.get()));
  mj_resetDataKeyframe(m.get(), d.get(), mj_name2id(m.get(), mjOBJ_KEY, "reference"));
  mj_forward(m.get(), d.get());
  std::vector<std::pair<int, Eigen::Vector3d>> free_bodies;
  for (int j = 0; j < m->njnt; ++j) {
    const int b = m->jnt_bodyid[j];
    if (m->jnt_type[j] == mjJNT_FREE &&
        std::string(mj_id2name(m.get(), mjOBJ_JOINT, j)) != "root_joint") {
      free_bodies.emplace_back(
          b, Eigen::Vector3d(d->xpos[3 * b], d->xpos[3 * b + 1], d->xpos[3 * b + 2]));
    }
  }
  for (int i = 0; i < 500; ++i) mj_step(m.get(), d.get());
  for (const auto& [b, p0] : free_bodies) {
    const Eigen::Vector3d p(d->xpos[3 * b], d->xpos[3 * b + 1], d->xpos[3 * b + 2]);
    EXPECT_LT((p - p0).norm(), 2e-3) << mj_id2name(m.get(), mjOBJ_BODY, b);
  }
}

// Every scene of models/scenes (its robot read from the scene's YAML).
std::vector<SceneCase> AllScenes() {
  std::vector<SceneCase> out;
  std::vector<std::filesystem::path> files;
  for (const auto& e : std::filesystem::directory_iterator(kModels + "/scenes")) {
    if (e.path().extension() == ".yaml") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  for (const auto& f : files) {
    out.push_back(
        {f.stem().string(), Robot(YAML::LoadFile(f.string())["robot"].as<std::string>())});
  }
  return out;
}

INSTANTIATE_TEST_SUITE_P(Scenes, SceneTest, ::testing::ValuesIn(AllScenes()),
                         [](const auto& info) { return info.param.scene; });

TEST(ObjectTest, EveryObjectFileLoads) {
  for (const char* object : {"plank", "table", "part", "ball", "pedestal", "bar", "drill", "box"}) {
    MjModelPtr m = LoadMjcf(kModels + "/objects/" + std::string(object) + ".xml");
    ASSERT_NE(m, nullptr) << object;
    EXPECT_EQ(m->nbody, 2) << object;  // world + the object
    EXPECT_GT(m->body_mass[1], 0.0) << object;
  }
}

}  // namespace
