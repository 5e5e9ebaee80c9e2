#pragma once
/// Device: the robot as an entity of the graph (SoT's Device). The loop calls Read(t) before
/// Graph::Evaluate (the measured state enters the source outputs) and Write(t) after it (the
/// commanded positions and velocities leave). Subclasses: sim::MujocoDevice (the simulated robot
/// in this process), controller::DriverDevice (a robot behind a driver process, over LCM).
/// @entity  inputs: q_command (nq), v_command (nv)
///          outputs (sources): q (nq), v (nv), effort (nv), wrench_<body> (6: force, torque;
///          world axes, about the body origin) for every measured body

#include <Eigen/Core>
#include <string>
#include <vector>

#include "marionette/graph/entity.h"

namespace marionette::graph {

class Device : public Entity {
 public:
  /// Declares the signals, starting at configuration q0 (nq) at rest; `nv` velocities;
  /// `measured_bodies` the bodies whose wrenches are measured (a humanoid's soles, fingers).
  Device(std::string name, const Eigen::VectorXd& q0, int nv,
         std::vector<std::string> measured_bodies)
      : Entity(std::move(name)), measured_bodies_(std::move(measured_bodies)) {
    q_command_ = &DeclareInput<Eigen::VectorXd>("q_command", q0);
    v_command_ = &DeclareParameter<Eigen::VectorXd>("v_command", Eigen::VectorXd::Zero(nv),
                                                    /*settable=*/false);
    q_ = &DeclareSource<Eigen::VectorXd>("q", q0);
    v_ = &DeclareSource<Eigen::VectorXd>("v", Eigen::VectorXd::Zero(nv));
    effort_ = &DeclareSource<Eigen::VectorXd>("effort", Eigen::VectorXd::Zero(nv));
    for (const std::string& body : measured_bodies_) {
      wrenches_.push_back(
          &DeclareSource<Eigen::VectorXd>("wrench_" + body, Eigen::VectorXd::Zero(6)));
    }
  }

  /// The measured state into the source outputs (before Graph::Evaluate).
  virtual void Read(const Tick& t) = 0;
  /// The command inputs (evaluated at t) to the robot (after Graph::Evaluate).
  virtual void Write(const Tick& t) = 0;

  InputSignal<Eigen::VectorXd>& q_command_input() { return *q_command_; }
  InputSignal<Eigen::VectorXd>& v_command_input() { return *v_command_; }
  OutputSignal<Eigen::VectorXd>& q_output() { return *q_; }
  OutputSignal<Eigen::VectorXd>& v_output() { return *v_; }
  OutputSignal<Eigen::VectorXd>& effort_output() { return *effort_; }
  OutputSignal<Eigen::VectorXd>& wrench_output(int i) { return *wrenches_.at(i); }
  const std::vector<std::string>& measured_bodies() const { return measured_bodies_; }

 protected:
  std::vector<std::string> measured_bodies_;
  InputSignal<Eigen::VectorXd>* q_command_{};
  InputSignal<Eigen::VectorXd>* v_command_{};
  OutputSignal<Eigen::VectorXd>* q_{};
  OutputSignal<Eigen::VectorXd>* v_{};
  OutputSignal<Eigen::VectorXd>* effort_{};
  std::vector<OutputSignal<Eigen::VectorXd>*> wrenches_;
};

}  // namespace marionette::graph
