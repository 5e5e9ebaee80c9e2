#pragma once
/// MujocoDevice: the simulated robot in this process as the graph's device (graph/device.h).
///
/// Per control tick: Read(t) runs mj_step1 and writes the measured state into the source
/// outputs; the graph evaluates; Write(t) sends the commanded positions and velocities to the
/// position servos and runs mj_step2 (plus extra physics steps when the MuJoCo timestep is
/// smaller than the control period). Efforts and contact wrenches are those of the last
/// completed physics step.

#include <string>
#include <vector>

#include "marionette/graph/device.h"
#include "marionette/sim/mujoco_scene.h"

namespace marionette::sim {

/// Reads a scene's robot the way a device measures it: q and v now, efforts and contact wrenches
/// of the last completed physics step. Shared by MujocoDevice and marionette-sim.
class SceneMeasurement {
 public:
  /// `scene` must outlive this; throws SimError on an unknown body.
  SceneMeasurement(const MujocoScene* scene, const std::vector<std::string>& bodies);
  /// After a physics step: the efforts and wrenches it ended with.
  void AfterStep();
  const Eigen::VectorXd& effort() const { return effort_; }  // (nv)
  /// Wrench of body i: (force, torque), world axes, about the body origin.
  const Eigen::Matrix<double, 6, 1>& wrench(int i) const { return wrenches_[i]; }
  int num_bodies() const { return static_cast<int>(body_ids_.size()); }

 private:
  const MujocoScene* scene_;
  std::vector<int> body_ids_;
  Eigen::VectorXd effort_;  // (nv)
  std::vector<Eigen::Matrix<double, 6, 1>> wrenches_;
};

class MujocoDevice final : public graph::Device {
 public:
  /// `scene` must outlive the device; `measured_bodies` are the robot bodies whose contact
  /// wrenches are measured (a humanoid: its sole links); `dt` is the control period.
  MujocoDevice(std::string name, MujocoScene* scene, std::vector<std::string> measured_bodies,
               double dt);
  const char* type_name() const override { return "MujocoDevice"; }

  /// mj_step1 and measurements into the source outputs (before Graph::Evaluate).
  void Read(const graph::Tick& t) override;
  /// Servo targets from the command inputs (evaluated at t) and mj_step2 (after Evaluate).
  void Write(const graph::Tick& t) override;

  const std::vector<std::string>& contact_bodies() const { return measured_bodies(); }
  const MujocoScene& scene() const { return *scene_; }

 private:
  MujocoScene* scene_;
  int substeps_;
  SceneMeasurement measurement_;
};

}  // namespace marionette::sim
