#include "marionette/sot/kinematics.h"

#include <algorithm>
#include <cstdlib>
#include <fstream>

#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/parsers/srdf.hpp>
#include <pinocchio/parsers/urdf.hpp>

namespace marionette::sot {

BaseJoint ParseBaseJoint(const std::string& name) {
  if (name == "fixed") return BaseJoint::kFixed;
  if (name == "free_flyer") return BaseJoint::kFreeFlyer;
  if (name == "planar") return BaseJoint::kPlanar;
  throw SotError("unknown base joint '" + name + "': expected fixed, free_flyer or planar");
}

namespace {
void CheckReadable(const std::string& path, const char* what) {
  if (!std::ifstream(path).good()) throw SotError(std::string(what) + " not found: " + path);
}
}  // namespace

ModelPtr LoadModel(const std::string& urdf_path, BaseJoint base, const std::string& srdf_path) {
  CheckReadable(urdf_path, "URDF");
  auto model = std::make_shared<pinocchio::Model>();
  switch (base) {
    case BaseJoint::kFixed:
      pinocchio::urdf::buildModel(urdf_path, *model);
      break;
    case BaseJoint::kFreeFlyer:
      pinocchio::urdf::buildModel(urdf_path, pinocchio::JointModelFreeFlyer(), *model);
      break;
    case BaseJoint::kPlanar:
      pinocchio::urdf::buildModel(urdf_path, pinocchio::JointModelPlanar(), *model);
      break;
  }
  if (!srdf_path.empty()) {
    CheckReadable(srdf_path, "SRDF");
    pinocchio::srdf::loadReferenceConfigurations(*model, srdf_path, /*verbose=*/false);
  }
  return model;
}

std::string ExampleRobotDataDir() {
  if (const char* dir = std::getenv("MARIONETTE_ROBOT_DATA_DIR"); dir != nullptr && *dir != 0) {
    return dir;
  }
  return MARIONETTE_EXAMPLE_ROBOT_DATA_DIR;
}

FrameRef MakeFrameRef(const pinocchio::Model& model, const std::string& frame_name,
                      const std::string& who) {
  if (!model.existFrame(frame_name)) {
    // Suggest frames sharing the first word ("gripper_left" -> gripper_left_*).
    const std::string stem = frame_name.substr(0, frame_name.find('_', frame_name.find('_') + 1));
    std::string similar;
    int shown = 0;
    for (const auto& f : model.frames) {
      if (f.name.find(stem) != std::string::npos && shown < 8) {
        similar += (shown++ ? ", " : "") + f.name;
      }
    }
    throw SotError(who + ": unknown frame '" + frame_name + "' in model '" + model.name + "'" +
                   (similar.empty() ? "" : " (similar: " + similar + ")"));
  }
  FrameRef f;
  f.name = frame_name;
  f.frame = model.getFrameId(frame_name);
  f.joint = model.frames[f.frame].parentJoint;
  for (pinocchio::JointIndex j : model.supports[f.joint]) {
    for (int k = 0; k < model.nvs[j]; ++k) f.columns.push_back(model.idx_vs[j] + k);
  }
  std::sort(f.columns.begin(), f.columns.end());
  return f;
}

Kinematics::Kinematics(ModelPtr model)
    : model_(std::move(model)), data_(*model_), q_(pinocchio::neutral(*model_)) {
  Compute(q_);
}

void Kinematics::Compute(const Eigen::Ref<const Eigen::VectorXd>& q) {
  q_ = q;
  pinocchio::forwardKinematics(*model_, data_, q_);
  // Also fills data_.J, the world Jacobians of every joint (computeJointJacobians' output).
  pinocchio::jacobianCenterOfMass(*model_, data_, /*computeSubtreeComs=*/false);
  pinocchio::updateFramePlacements(*model_, data_);
}

void LocalFrameJacobian(const Kinematics& kinematics, const FrameRef& f,
                        Eigen::Ref<Matrix6Xd> J_F) {
  // data.J column c is the twist of joint axis c expressed in world at the world origin
  // (v_O, w). The same motion seen in F: w_F = R_WF^T w, v_F = R_WF^T (v_O + w x p_WF).
  const pinocchio::SE3& X_WF = kinematics.placement(f);
  const Eigen::Matrix3d R_FW = X_WF.rotation().transpose();
  const Eigen::Vector3d& p_WF = X_WF.translation();
  const auto& J_W = kinematics.data().J;
  for (int c : f.columns) {
    const Eigen::Vector3d v_O = J_W.col(c).head<3>();
    const Eigen::Vector3d w = J_W.col(c).tail<3>();
    J_F.col(c).head<3>().noalias() = R_FW * (v_O + w.cross(p_WF));
    J_F.col(c).tail<3>().noalias() = R_FW * w;
  }
}

std::vector<int> MaskIndices(const Mask& mask, int full_dimension, const std::string& who) {
  std::vector<int> kept;
  if (mask.empty()) {
    for (int i = 0; i < full_dimension; ++i) kept.push_back(i);
    return kept;
  }
  if (static_cast<int>(mask.size()) != full_dimension) {
    throw SotError(who + ": mask of " + std::to_string(mask.size()) + " components, expected " +
                   std::to_string(full_dimension));
  }
  for (int i = 0; i < full_dimension; ++i) {
    if (mask[i]) kept.push_back(i);
  }
  if (kept.empty()) throw SotError(who + ": the mask selects no component");
  return kept;
}

}  // namespace marionette::sot
