// The UR10 gripper's right finger in MuJoCo follows finger_joint as the URDF's <mimic> says:
// the generated models/ur10/ur10.xml ties finger_mimic_joint to it by an
// <equality><joint>. Reference: Pinocchio on the full URDF — models/ur10/ur10.urdf with the mimic
// joint made prismatic (the URDF fixes it for the controller's model) and set to multiplier q +
// offset as read from the URDF text. Then the physics the grip-force estimate relies on
// (robot.yaml: torque_per_effort 0.5, lever_arm 1): a free box closed on by the servo is
// squeezed by each finger with half the motor force (virtual work: tau dq = F dq + F dq).
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <map>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>
#include <pinocchio/parsers/urdf.hpp>
#include <regex>
#include <string>

namespace {

namespace pin = pinocchio;

const std::string kModels = MARIONETTE_MODELS_DIR;

struct Mimic {
  std::string driver;
  double multiplier = 1.0;
  double offset = 0.0;
};

std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// The <mimic> of every joint of `urdf` that has one (joint name -> mimic).
std::map<std::string, Mimic> UrdfMimics(const std::string& urdf) {
  std::map<std::string, Mimic> out;
  const std::regex joint(R"re(<joint name="([^"]+)"[^>]*>([\s\S]*?)</joint>)re");
  const std::regex mimic(R"re(<mimic joint="([^"]+)" multiplier="([^"]+)" offset="([^"]+)")re");
  for (std::sregex_iterator it(urdf.begin(), urdf.end(), joint), end; it != end; ++it) {
    const std::string body = (*it)[2];
    std::smatch m;
    if (std::regex_search(body, m, mimic)) out[(*it)[1]] = {m[1], std::stod(m[2]), std::stod(m[3])};
  }
  return out;
}

// The URDF with its fixed mimic joints made prismatic: the "full" gripper kinematics.
std::string FullUrdf(const std::string& urdf, const std::map<std::string, Mimic>& mimics) {
  std::string out = urdf;
  for (const auto& [name, _] : mimics) {
    const std::string from = "<joint name=\"" + name + "\" type=\"fixed\">";
    const size_t at = out.find(from);
    if (at != std::string::npos) {
      out.replace(at, from.size(),
                  "<joint name=\"" + name + "\" type=\"prismatic\">" +
                      "<limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/>");
    }
  }
  return out;
}

Eigen::Isometry3d MujocoBodyPose(const mjModel* m, const mjData* d, const std::string& body) {
  const int b = mj_name2id(m, mjOBJ_BODY, body.c_str());
  EXPECT_GE(b, 0) << body;
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(d->xmat + 9 * b);
  X.translation() = Eigen::Map<const Eigen::Vector3d>(d->xpos + 3 * b);
  return X;
}

TEST(GripperMimicTest, FingersFollowTheDrivenJointAsTheUrdfMimicSays) {
  const std::string urdf = ReadFile(kModels + "/ur10/ur10.urdf");
  const std::map<std::string, Mimic> mimics = UrdfMimics(urdf);
  ASSERT_EQ(mimics.size(), 1u) << "the right finger";
  ASSERT_EQ(mimics.begin()->second.driver, "finger_joint");
  pin::Model full;
  pin::urdf::buildModelFromXML(FullUrdf(urdf, mimics), full);
  pin::Data data(full);

  char error[1000] = "";
  mjModel* m = mj_loadXML((kModels + "/ur10/ur10.xml").c_str(), nullptr, error, sizeof(error));
  ASSERT_NE(m, nullptr) << error;
  mjData* d = mj_makeData(m);
  mj_resetDataKeyframe(m, d, mj_name2id(m, mjOBJ_KEY, "reference"));
  m->opt.gravity[2] = 0.0;
  m->opt.disableflags |= mjDSBL_CONTACT;

  double largest_motion = 0.0;
  for (const double target : {0.01, 0.025, 0.04}) {
    d->ctrl[mj_name2id(m, mjOBJ_ACTUATOR, "finger_joint")] = target;
    for (int i = 0; i < 1000; ++i) mj_step(m, d);  // 1 s: the servo settles
    const int jd = mj_name2id(m, mjOBJ_JOINT, "finger_joint");
    const double q_driven = d->qpos[m->jnt_qposadr[jd]];
    EXPECT_NEAR(q_driven, target, 1e-3);
    // Pinocchio, the full gripper: the driven value measured in MuJoCo, the mimic from the URDF.
    Eigen::VectorXd q = pin::neutral(full);
    for (int j = 1; j < static_cast<int>(full.joints.size()); ++j) {  // the arm as in the keyframe
      const int id = mj_name2id(m, mjOBJ_JOINT, full.names[j].c_str());
      if (id >= 0) q[full.joints[j].idx_q()] = d->qpos[m->jnt_qposadr[id]];
    }
    for (const auto& [name, mimic] : mimics) {
      q[full.joints[full.getJointId(name)].idx_q()] = mimic.multiplier * q_driven + mimic.offset;
    }
    pin::framesForwardKinematics(full, data, q);
    const pin::SE3 X_WB_pin = data.oMf[full.getFrameId("gripper_link")];
    const Eigen::Isometry3d X_WB_mj = MujocoBodyPose(m, d, "gripper_link");
    for (const char* link : {"finger_left_link", "finger_right_link"}) {
      const pin::SE3 X_BF_pin = X_WB_pin.actInv(data.oMf[full.getFrameId(link)]);
      const Eigen::Isometry3d X_BF_mj = X_WB_mj.inverse() * MujocoBodyPose(m, d, link);
      // 0.1 mm / 1 mrad: the equality is a soft constraint (solref 5 ms), not exact.
      EXPECT_LT((X_BF_mj.translation() - X_BF_pin.translation()).norm(), 1e-4)
          << link << " at " << target;
      const Eigen::AngleAxisd dR(X_BF_mj.linear().transpose() * X_BF_pin.rotation());
      EXPECT_LT(std::abs(dR.angle()), 1e-3) << link << " at " << target;
    }
    // The fingers close symmetrically: the gap shrinks by twice the driven travel.
    const double gap = (MujocoBodyPose(m, d, "finger_left_link").translation() -
                        MujocoBodyPose(m, d, "finger_right_link").translation())
                           .norm();
    largest_motion = std::max(largest_motion, 0.17 - gap);
    EXPECT_NEAR(gap, 0.17 - 2 * q_driven, 2e-4) << "at " << target;
  }
  EXPECT_GT(largest_motion, 0.07) << "the gap closes by 2 x 4 cm";
  mj_deleteData(d);
  mj_deleteModel(m);
}

// Normal contact force between a geom of `body` and any geom of body `other` [N].
double ContactForce(const mjModel* m, const mjData* d, int body, int other) {
  double f = 0.0;
  for (int i = 0; i < d->ncon; ++i) {
    const mjContact& c = d->contact[i];
    const int b1 = m->geom_bodyid[c.geom1], b2 = m->geom_bodyid[c.geom2];
    if ((b1 == body && b2 == other) || (b1 == other && b2 == body)) {
      mjtNum wrench[6];
      mj_contactForce(m, d, i, wrench);
      f += wrench[0];  // normal component, contact frame
    }
  }
  return f;
}

TEST(GripperMimicTest, EachFingerSqueezesAFreeBoxWithHalfTheMotorForce) {
  char error[1000] = "";
  mjModel* m =
      mj_loadXML((kModels + "/scenes/ur10_box.xml").c_str(), nullptr, error, sizeof(error));
  ASSERT_NE(m, nullptr) << error;
  mjData* d = mj_makeData(m);
  mj_resetDataKeyframe(m, d, mj_name2id(m, mjOBJ_KEY, "reference"));
  m->opt.gravity[2] = 0.0;  // the box floats: only the fingers push it
  mj_forward(m, d);
  // The box where the handle box/top meets the gripper frame ur10/gripper: its centre 3.5 cm
  // beyond the grasp frame along the approach (x of the gripper frame), faces along y.
  const int site = mj_name2id(m, mjOBJ_SITE, "ur10/gripper");
  const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> R(d->site_xmat + 9 * site);
  const Eigen::Vector3d p =
      Eigen::Map<const Eigen::Vector3d>(d->site_xpos + 3 * site) + 0.035 * R.col(0);
  // Box frame: z = -x_gripper (the handle's x points down into the box), x = y_gripper.
  Eigen::Matrix3d R_box;
  R_box.col(0) = R.col(1);
  R_box.col(2) = -R.col(0);
  R_box.col(1) = R_box.col(2).cross(R_box.col(0));
  const Eigen::Quaterniond quat(R_box);
  const int box_joint = mj_name2id(m, mjOBJ_JOINT, "box");
  mjtNum* qbox = d->qpos + m->jnt_qposadr[box_joint];
  for (int k = 0; k < 3; ++k) qbox[k] = p[k];
  qbox[3] = quat.w(), qbox[4] = quat.x(), qbox[5] = quat.y(), qbox[6] = quat.z();

  const int actuator = mj_name2id(m, mjOBJ_ACTUATOR, "finger_joint");
  d->ctrl[actuator] = 0.02;  // 5 mm past the box's faces: 2000 N/m x 5 mm = 10 N of motor force
  for (int i = 0; i < 3000; ++i) mj_step(m, d);  // 3 s: closes, touches, settles
  const int box = mj_name2id(m, mjOBJ_BODY, "box");
  const double left = ContactForce(m, d, mj_name2id(m, mjOBJ_BODY, "finger_left_link"), box);
  const double right = ContactForce(m, d, mj_name2id(m, mjOBJ_BODY, "finger_right_link"), box);
  const double motor = d->actuator_force[actuator];
  std::printf("motor %.3f N, left finger %.3f N, right finger %.3f N\n", motor, left, right);
  EXPECT_GT(motor, 8.0) << "the servo pushes (10 N expected)";
  EXPECT_NEAR(left, 0.5 * motor, 0.05 * motor) << "right " << right << " motor " << motor;
  EXPECT_NEAR(right, 0.5 * motor, 0.05 * motor) << "left " << left << " motor " << motor;
  mj_deleteData(d);
  mj_deleteModel(m);
}

}  // namespace
