#include "marionette/walk/pattern_generator.h"

#include <stdexcept>

namespace marionette::walk {
namespace {

Eigen::VectorXd RestCart(const Eigen::Vector3d& com) {
  Eigen::VectorXd x = Eigen::VectorXd::Zero(8);
  x[0] = com[0];
  x[3] = com[1];
  return x;
}

}  // namespace

PatternGenerator::PatternGenerator(std::string name, const PreviewControlParams& params,
                                   const Eigen::Vector3d& com)
    : PatternGenerator(std::move(name),
                       std::make_shared<const PreviewGains>(ComputePreviewGains(params)), com) {}

PatternGenerator::PatternGenerator(std::string name, std::shared_ptr<const PreviewGains> gains,
                                   const Eigen::Vector3d& com)
    : Entity(std::move(name)), gains_(std::move(gains)), com_z_(com[2]) {
  if (!gains_) throw std::invalid_argument("PatternGenerator '" + this->name() + "': null gains");
  if (!com.allFinite())
    throw std::invalid_argument("PatternGenerator '" + this->name() + "': non-finite CoM");
  const int N = preview_samples();
  zmp_window_ = &DeclareInput<Eigen::MatrixXd>("zmp_window", Eigen::MatrixXd::Zero(2, N + 1));
  cart_ = &DeclareState<Eigen::VectorXd>("cart", RestCart(com), &PatternGenerator::UpdateCart,
                                         {zmp_window_});
  com_ = &DeclareOutput<Eigen::VectorXd>("com", Eigen::VectorXd(com), &PatternGenerator::CalcCom,
                                         {cart_});
  com_velocity_ = &DeclareOutput<Eigen::VectorXd>("com_velocity", Eigen::VectorXd::Zero(3),
                                                  &PatternGenerator::CalcComVelocity, {cart_});
  com_acceleration_ =
      &DeclareOutput<Eigen::VectorXd>("com_acceleration", Eigen::VectorXd::Zero(3),
                                      &PatternGenerator::CalcComAcceleration, {cart_});
  zmp_ = &DeclareOutput<Eigen::VectorXd>("zmp", Eigen::VectorXd(com.head<2>()),
                                         &PatternGenerator::CalcZmp, {cart_});
}

void PatternGenerator::Reset(const Eigen::Vector3d& com) {
  Eigen::VectorXd& x = cart_->mutable_value();
  x.setZero();
  x[0] = com[0];
  x[3] = com[1];
  com_z_ = com[2];
}

void PatternGenerator::UpdateCart(const graph::Tick& t, const Eigen::VectorXd& x,
                                  Eigen::VectorXd* next) const {
  const Eigen::MatrixXd& window = zmp_window_->Eval(t);  // 2 x (N+1), column-major: stride 2
  for (int axis = 0; axis < 2; ++axis) {
    CartAxis cart;
    cart.x = x.segment<3>(3 * axis);
    cart.error_sum = x[6 + axis];
    PreviewStep(*gains_, window.data() + axis, /*stride=*/2, &cart);
    next->segment<3>(3 * axis) = cart.x;
    (*next)[6 + axis] = cart.error_sum;
  }
}

void PatternGenerator::CalcCom(const graph::Tick& t, Eigen::VectorXd* out) const {
  const Eigen::VectorXd& x = cart_->Eval(t);
  *out << x[0], x[3], com_z_;
}

void PatternGenerator::CalcComVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
  const Eigen::VectorXd& x = cart_->Eval(t);
  *out << x[1], x[4], 0.0;
}

void PatternGenerator::CalcComAcceleration(const graph::Tick& t, Eigen::VectorXd* out) const {
  const Eigen::VectorXd& x = cart_->Eval(t);
  *out << x[2], x[5], 0.0;
}

void PatternGenerator::CalcZmp(const graph::Tick& t, Eigen::VectorXd* out) const {
  const Eigen::VectorXd& x = cart_->Eval(t);
  const Eigen::RowVector3d& C = gains_->C;
  *out << C.dot(x.segment<3>(0)), C.dot(x.segment<3>(3));
}

}  // namespace marionette::walk
