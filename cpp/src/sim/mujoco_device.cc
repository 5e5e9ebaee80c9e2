#include "marionette/sim/mujoco_device.h"

namespace marionette::sim {

namespace {

Eigen::VectorXd RobotConfiguration(const MujocoScene& scene) {
  Eigen::VectorXd q(scene.robot_nq()), v(scene.robot_nv());
  scene.ReadRobotState(q, v);
  return q;
}

}  // namespace

SceneMeasurement::SceneMeasurement(const MujocoScene* scene, const std::vector<std::string>& bodies)
    : scene_(scene),
      effort_(Eigen::VectorXd::Zero(scene->robot_nv())),
      wrenches_(bodies.size(), Eigen::Matrix<double, 6, 1>::Zero()) {
  for (const std::string& body : bodies) body_ids_.push_back(scene_->BodyId(body));  // throws
}

void SceneMeasurement::AfterStep() {
  scene_->ReadJointEfforts(effort_);
  for (size_t i = 0; i < body_ids_.size(); ++i) {
    const ContactWrench w = scene_->BodyContactWrench(body_ids_[i]);
    wrenches_[i].head<3>() = w.force;
    wrenches_[i].tail<3>() = w.torque;
  }
}

MujocoDevice::MujocoDevice(std::string name, MujocoScene* scene,
                           std::vector<std::string> measured_bodies, double dt)
    : Device(std::move(name), RobotConfiguration(*scene), scene->robot_nv(),
             std::move(measured_bodies)),
      scene_(scene),
      substeps_(scene->SubstepsFor(dt)),
      measurement_(scene, measured_bodies_) {
  Eigen::VectorXd q0(scene->robot_nq()), v0(scene->robot_nv());
  scene_->ReadRobotState(q0, v0);
  v_->mutable_value() = v0;
}

void MujocoDevice::Read(const graph::Tick&) {
  scene_->Step1();
  scene_->ReadRobotState(q_->mutable_value(), v_->mutable_value());
  effort_->mutable_value() = measurement_.effort();
  for (size_t i = 0; i < wrenches_.size(); ++i)
    wrenches_[i]->mutable_value() = measurement_.wrench(static_cast<int>(i));
}

void MujocoDevice::Write(const graph::Tick& t) {
  scene_->WriteServoTargets(q_command_->Eval(t), v_command_->Eval(t));
  scene_->Step2(substeps_);
  measurement_.AfterStep();
}

}  // namespace marionette::sim
