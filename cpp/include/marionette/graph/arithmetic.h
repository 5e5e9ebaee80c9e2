#pragma once
/// Small operator entities (SoT's sot-core "operator" family): constants, sums, gains,
/// products, integrators. Building blocks for scripts, tests and benchmarks.

#include <Eigen/Core>
#include <string>

#include "marionette/graph/entity.h"

namespace marionette::graph {

/// out = value, with `value` a parameter (settable while running unless told otherwise).
/// @entity  inputs: value (n)   outputs: out (n)
class VectorConstant final : public Entity {
 public:
  VectorConstant(std::string name, const Eigen::VectorXd& value, bool settable = true);
  const char* type_name() const override { return "VectorConstant"; }
  InputSignal<Eigen::VectorXd>& value_input() { return *value_; }
  OutputSignal<Eigen::VectorXd>& out_output() { return *out_; }

 private:
  void CalcOut(const Tick& t, Eigen::VectorXd* out) const;
  InputSignal<Eigen::VectorXd>* value_{};
  OutputSignal<Eigen::VectorXd>* out_{};
};

/// out = in0 + in1 + ... + in{k-1}.
/// @entity  inputs: in0 .. in{k-1} (n)   outputs: out (n)
class VectorSum final : public Entity {
 public:
  VectorSum(std::string name, int n, int num_inputs);
  const char* type_name() const override { return "VectorSum"; }
  InputSignal<Eigen::VectorXd>& in(int i) { return *ins_.at(i); }
  OutputSignal<Eigen::VectorXd>& out_output() { return *out_; }

 private:
  void CalcOut(const Tick& t, Eigen::VectorXd* out) const;
  std::vector<InputSignal<Eigen::VectorXd>*> ins_;
  OutputSignal<Eigen::VectorXd>* out_{};
};

/// out = gain * in, with `gain` a settable parameter.
/// @entity  inputs: in (n), gain (scalar)   outputs: out (n)
class VectorGain final : public Entity {
 public:
  VectorGain(std::string name, int n, double gain);
  const char* type_name() const override { return "VectorGain"; }
  InputSignal<Eigen::VectorXd>& in_input() { return *in_; }
  InputSignal<double>& gain_input() { return *gain_; }
  OutputSignal<Eigen::VectorXd>& out_output() { return *out_; }

 private:
  void CalcOut(const Tick& t, Eigen::VectorXd* out) const;
  InputSignal<Eigen::VectorXd>* in_{};
  InputSignal<double>* gain_{};
  OutputSignal<Eigen::VectorXd>* out_{};
};

/// out = matrix * vector.
/// @entity  inputs: matrix (rows x cols), vector (cols)   outputs: out (rows)
class MatrixVectorProduct final : public Entity {
 public:
  MatrixVectorProduct(std::string name, int rows, int cols);
  const char* type_name() const override { return "MatrixVectorProduct"; }
  InputSignal<Eigen::MatrixXd>& matrix_input() { return *matrix_; }
  InputSignal<Eigen::VectorXd>& vector_input() { return *vector_; }
  OutputSignal<Eigen::VectorXd>& out_output() { return *out_; }

 private:
  void CalcOut(const Tick& t, Eigen::VectorXd* out) const;
  InputSignal<Eigen::MatrixXd>* matrix_{};
  InputSignal<Eigen::VectorXd>* vector_{};
  OutputSignal<Eigen::VectorXd>* out_{};
};

/// Explicit Euler integrator: state x_{t+1} = x_t + dt * derivative_t.
/// @entity  inputs: derivative (n)   outputs: state (n, a state signal)
class VectorIntegrator final : public Entity {
 public:
  VectorIntegrator(std::string name, const Eigen::VectorXd& initial);
  const char* type_name() const override { return "VectorIntegrator"; }
  InputSignal<Eigen::VectorXd>& derivative_input() { return *derivative_; }
  OutputSignal<Eigen::VectorXd>& state_output() { return *state_; }

 private:
  void UpdateState(const Tick& t, const Eigen::VectorXd& x, Eigen::VectorXd* next) const;
  InputSignal<Eigen::VectorXd>* derivative_{};
  OutputSignal<Eigen::VectorXd>* state_{};
};

}  // namespace marionette::graph
