// TALOS' fingers in MuJoCo follow the gripper joint as the URDF's <mimic> says (issue 7): the
// generated models/talos/talos.xml ties each finger joint to gripper_<side>_joint by an
// <equality><joint>. Reference: Pinocchio on the full URDF — models/talos/talos.urdf with its
// mimic joints made revolute (the reduced URDF fixes them) and set to multiplier q + offset as
// read from the URDF text. The servo closes the driven joint in the simulation (contacts and
// gravity off: the fingers move on the equality alone); every finger body's pose relative to the
// gripper base must then be Pinocchio's at the simulated driven angle.
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
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

// The URDF with its fixed mimic joints made revolute: the "full" TALOS gripper kinematics.
std::string FullUrdf(const std::string& urdf, const std::map<std::string, Mimic>& mimics) {
  std::string out = urdf;
  for (const auto& [name, _] : mimics) {
    const std::string from = "<joint name=\"" + name + "\" type=\"fixed\">";
    const size_t at = out.find(from);
    if (at != std::string::npos) out.replace(at, from.size(), "<joint name=\"" + name + "\" type=\"revolute\">");
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
  const std::string urdf = ReadFile(kModels + "/talos/talos.urdf");
  const std::map<std::string, Mimic> mimics = UrdfMimics(urdf);
  ASSERT_EQ(mimics.size(), 12u) << "6 mimic joints per TALOS gripper";
  pin::Model full;
  pin::urdf::buildModelFromXML(FullUrdf(urdf, mimics), full);
  pin::Data data(full);

  char error[1000] = "";
  mjModel* m = mj_loadXML((kModels + "/talos/talos.xml").c_str(), nullptr, error, sizeof(error));
  ASSERT_NE(m, nullptr) << error;
  mjData* d = mj_makeData(m);
  mj_resetDataKeyframe(m, d, mj_name2id(m, mjOBJ_KEY, "reference"));
  m->opt.gravity[2] = 0.0;
  m->opt.disableflags |= mjDSBL_CONTACT;

  const char* fingers[] = {"motor_double", "inner_double", "fingertip_1", "fingertip_2",
                           "motor_single", "inner_single", "fingertip_3"};
  double largest_motion = 0.0;
  for (const double target : {-0.3, -0.7, -1.0}) {
    for (const char* side : {"left", "right"}) {
      const std::string joint = std::string("gripper_") + side + "_joint";
      d->ctrl[mj_name2id(m, mjOBJ_ACTUATOR, joint.c_str())] = target;
    }
    for (int i = 0; i < 1000; ++i) mj_step(m, d);  // 1 s: the servo settles
    for (const char* side : {"left", "right"}) {
      const std::string prefix = std::string("gripper_") + side + "_";
      const int jd = mj_name2id(m, mjOBJ_JOINT, (prefix + "joint").c_str());
      const double q_driven = d->qpos[m->jnt_qposadr[jd]];
      EXPECT_NEAR(q_driven, target, 0.02) << side;
      // Pinocchio, the full gripper: the driven angle measured in MuJoCo, the mimics from the URDF.
      Eigen::VectorXd q = pin::neutral(full);
      q[full.joints[full.getJointId(prefix + "joint")].idx_q()] = q_driven;
      for (const auto& [name, mimic] : mimics) {
        if (mimic.driver != prefix + "joint") continue;
        q[full.joints[full.getJointId(name)].idx_q()] = mimic.multiplier * q_driven + mimic.offset;
      }
      pin::framesForwardKinematics(full, data, q);
      const pin::SE3 X_WB_pin = data.oMf[full.getFrameId(prefix + "base_link")];
      const Eigen::Isometry3d X_WB_mj = MujocoBodyPose(m, d, prefix + "base_link");
      for (const char* finger : fingers) {
        const std::string link = prefix + finger + "_link";
        const pin::SE3 X_BF_pin = X_WB_pin.actInv(data.oMf[full.getFrameId(link)]);
        const Eigen::Isometry3d X_BF_mj = X_WB_mj.inverse() * MujocoBodyPose(m, d, link);
        // 0.1 mm / 1 mrad: the equalities are soft constraints (solref 5 ms), not exact.
        EXPECT_LT((X_BF_mj.translation() - X_BF_pin.translation()).norm(), 1e-4) << link << " at " << target;
        const Eigen::AngleAxisd dR(X_BF_mj.linear().transpose() * X_BF_pin.rotation());
        EXPECT_LT(std::abs(dR.angle()), 1e-3) << link << " at " << target;
        // The finger really moved from where the reduced model (mimics at 0) keeps it.
        Eigen::VectorXd q0 = q;
        for (const auto& [name, mimic] : mimics) q0[full.joints[full.getJointId(name)].idx_q()] = 0.0;
        q0[full.joints[full.getJointId(prefix + "joint")].idx_q()] = 0.0;
        pin::Data data0(full);
        pin::framesForwardKinematics(full, data0, q0);
        const pin::SE3 X_BF_open =
            data0.oMf[full.getFrameId(prefix + "base_link")].actInv(data0.oMf[full.getFrameId(link)]);
        largest_motion = std::max(largest_motion, (X_BF_open.translation() - X_BF_pin.translation()).norm());
      }
    }
  }
  EXPECT_GT(largest_motion, 0.02) << "the fingertips travel centimetres between open and closed";
  mj_deleteData(d);
  mj_deleteModel(m);
}

}  // namespace
