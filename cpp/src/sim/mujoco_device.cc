#include "marionette/sim/mujoco_device.h"

namespace marionette::sim {

MujocoDevice::MujocoDevice(std::string name, MujocoScene* scene,
                           std::vector<std::string> contact_bodies, double dt)
    : Entity(std::move(name)),
      scene_(scene),
      contact_bodies_(std::move(contact_bodies)),
      substeps_(scene->SubstepsFor(dt)),
      last_effort_(Eigen::VectorXd::Zero(scene->robot_nv())),
      last_wrenches_(contact_bodies_.size(), Eigen::Matrix<double, 6, 1>::Zero()) {
  const int nq = scene_->robot_nq(), nv = scene_->robot_nv();
  for (const std::string& body : contact_bodies_) {
    contact_body_ids_.push_back(scene_->BodyId(body));  // throws if unknown
  }
  Eigen::VectorXd q0(nq), v0(nv);
  scene_->ReadRobotState(q0, v0);
  q_command_ = &DeclareInput<Eigen::VectorXd>("q_command", q0);
  v_command_ = &DeclareParameter<Eigen::VectorXd>("v_command", Eigen::VectorXd::Zero(nv),
                                                  /*settable=*/false);
  q_ = &DeclareSource<Eigen::VectorXd>("q", q0);
  v_ = &DeclareSource<Eigen::VectorXd>("v", v0);
  effort_ = &DeclareSource<Eigen::VectorXd>("effort", Eigen::VectorXd::Zero(nv));
  for (const std::string& body : contact_bodies_) {
    wrenches_.push_back(
        &DeclareSource<Eigen::VectorXd>("wrench_" + body, Eigen::VectorXd::Zero(6)));
  }
}

void MujocoDevice::Read(const graph::Tick&) {
  scene_->Step1();
  scene_->ReadRobotState(q_->mutable_value(), v_->mutable_value());
  effort_->mutable_value() = last_effort_;
  for (size_t i = 0; i < wrenches_.size(); ++i) wrenches_[i]->mutable_value() = last_wrenches_[i];
}

void MujocoDevice::Write(const graph::Tick& t) {
  scene_->WriteServoTargets(q_command_->Eval(t), v_command_->Eval(t));
  scene_->Step2(substeps_);
  MeasureAfterStep();
}

void MujocoDevice::MeasureAfterStep() {
  scene_->ReadJointEfforts(last_effort_);
  for (size_t i = 0; i < contact_bodies_.size(); ++i) {
    const ContactWrench w = scene_->BodyContactWrench(contact_body_ids_[i]);
    last_wrenches_[i].head<3>() = w.force;
    last_wrenches_[i].tail<3>() = w.torque;
  }
}

}  // namespace marionette::sim
