#pragma once
/// MujocoDevice: the simulated robot as an entity of the graph (SoT's Device).
///
/// Per control tick: Read(t) runs mj_step1 and writes the measured state into the source
/// outputs; the graph evaluates; Write(t) sends the commanded positions and velocities to the
/// position servos and runs mj_step2 (plus extra physics steps when the MuJoCo timestep is
/// smaller than the control period). Efforts and contact wrenches are those of the last
/// completed physics step.
/// @entity  inputs: q_command (nq), v_command (nv)
///          outputs (sources): q (nq), v (nv), effort (nv), wrench_<body> (6: force, torque;
///          world axes, about the body origin) for every contact body given

#include <memory>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"
#include "marionette/sim/mujoco_scene.h"

namespace marionette::sim {

class MujocoDevice final : public graph::Entity {
 public:
  /// `scene` must outlive the device; `contact_bodies` are the robot bodies whose contact
  /// wrenches are measured (a humanoid: its sole links); `dt` is the control period.
  MujocoDevice(std::string name, MujocoScene* scene, std::vector<std::string> contact_bodies,
               double dt);
  const char* type_name() const override { return "MujocoDevice"; }

  /// mj_step1 and measurements into the source outputs (before Graph::Evaluate).
  void Read(const graph::Tick& t);
  /// Servo targets from the command inputs (evaluated at t) and mj_step2 (after Evaluate).
  void Write(const graph::Tick& t);

  graph::InputSignal<Eigen::VectorXd>& q_command_input() { return *q_command_; }
  graph::InputSignal<Eigen::VectorXd>& v_command_input() { return *v_command_; }
  graph::OutputSignal<Eigen::VectorXd>& q_output() { return *q_; }
  graph::OutputSignal<Eigen::VectorXd>& v_output() { return *v_; }
  graph::OutputSignal<Eigen::VectorXd>& effort_output() { return *effort_; }
  graph::OutputSignal<Eigen::VectorXd>& wrench_output(int i) { return *wrenches_.at(i); }
  const std::vector<std::string>& contact_bodies() const { return contact_bodies_; }
  const MujocoScene& scene() const { return *scene_; }

 private:
  void MeasureAfterStep();

  MujocoScene* scene_;
  std::vector<std::string> contact_bodies_;
  std::vector<int> contact_body_ids_;
  int substeps_;
  graph::InputSignal<Eigen::VectorXd>* q_command_{};
  graph::InputSignal<Eigen::VectorXd>* v_command_{};
  graph::OutputSignal<Eigen::VectorXd>* q_{};
  graph::OutputSignal<Eigen::VectorXd>* v_{};
  graph::OutputSignal<Eigen::VectorXd>* effort_{};
  std::vector<graph::OutputSignal<Eigen::VectorXd>*> wrenches_;
  Eigen::VectorXd last_effort_;  // (nv) after the last physics step
  std::vector<Eigen::Matrix<double, 6, 1>> last_wrenches_;
};

}  // namespace marionette::sim
