#include "marionette/walk/preview_control.h"

#include <Eigen/LU>
#include <cmath>
#include <stdexcept>
#include <string>

namespace marionette::walk {
namespace {

void Require(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("PreviewControlParams: " + what);
}

}  // namespace

void PreviewControlParams::Check() const {
  Require(std::isfinite(dt) && dt > 0.0 && dt <= 0.1,
          "dt must be in (0, 0.1] s, got " + std::to_string(dt));
  Require(std::isfinite(com_height) && com_height > 0.05 && com_height < 10.0,
          "com_height must be in (0.05, 10) m, got " + std::to_string(com_height));
  Require(std::isfinite(gravity) && gravity > 0.0, "gravity must be > 0");
  Require(std::isfinite(preview_time) && preview_time >= dt && preview_time <= 10.0,
          "preview_time must be in [dt, 10] s, got " + std::to_string(preview_time));
  Require(std::isfinite(qe) && qe > 0.0, "qe must be > 0");
  Require(std::isfinite(r), "r must be finite");
}

double PreviewControlParams::EffectiveR() const {
  if (r > 0.0) return r;
  const double ratio = 5e-3 / dt;  // Kajita's R = 1e-6 at T = 5 ms, R T² held constant
  return 1e-6 * ratio * ratio;
}

int PreviewControlParams::PreviewSamples() const {
  return static_cast<int>(std::lround(preview_time / dt));
}

AugmentedSystem MakeAugmentedSystem(const PreviewControlParams& p) {
  const double T = p.dt;
  Eigen::Matrix3d A;
  A << 1.0, T, T * T / 2.0, 0.0, 1.0, T, 0.0, 0.0, 1.0;
  const Eigen::Vector3d B(T * T * T / 6.0, T * T / 2.0, T);
  const Eigen::RowVector3d C(1.0, 0.0, -p.com_height / p.gravity);
  // Katayama's augmented state (p(k) - p_ref(k), Δx(k)): the ZMP error integrates the state
  // increments, so the integral action falls out of the incremental cost.
  AugmentedSystem s;
  s.A.setZero();
  s.A(0, 0) = 1.0;
  s.A.block<1, 3>(0, 1) = C * A;
  s.A.block<3, 3>(1, 1) = A;
  s.B << C.dot(B), B;  // C B is 1x1: a scalar (GCC 12 misreads the 1x1 temporary's bounds)
  s.Q.setZero();
  s.Q(0, 0) = p.qe;  // Qx = 0 (Kajita's choice)
  s.R = p.EffectiveR();
  return s;
}

double RiccatiResidual(const AugmentedSystem& s, const Eigen::Matrix4d& P) {
  const double denominator = s.R + s.B.dot(P * s.B);
  const Eigen::RowVector4d BtPA = s.B.transpose() * P * s.A;
  const Eigen::Matrix4d rhs =
      s.A.transpose() * P * s.A - BtPA.transpose() * BtPA / denominator + s.Q;
  return (P - rhs).cwiseAbs().maxCoeff();
}

PreviewGains ComputePreviewGains(const PreviewControlParams& params) {
  params.Check();
  const AugmentedSystem s = MakeAugmentedSystem(params);

  // Structured doubling (Chu, Fan, Lin 2005): with A0 = A, G0 = B R⁻¹ Bᵀ, H0 = Q,
  //   W = I + G H,  A' = A W⁻¹ A,  G' = G + A W⁻¹ G Aᵀ,  H' = H + Aᵀ H W⁻¹ A,
  // H converges quadratically to the stabilising DARE solution. Plain Riccati iteration
  // converges like ρ^{2k} (ρ the slowest closed-loop pole, ≈ 0.99 at T = 1 ms): thousands of
  // steps; doubling takes a few dozen.
  Eigen::Matrix4d Ak = s.A, G = s.B * s.B.transpose() / s.R, H = s.Q;
  const Eigen::Matrix4d I = Eigen::Matrix4d::Identity();
  int iterations = 0;
  for (; iterations < 100; ++iterations) {
    const Eigen::PartialPivLU<Eigen::Matrix4d> W(I + G * H);
    const Eigen::Matrix4d WinvA = W.solve(Ak);
    const Eigen::Matrix4d WinvG = W.solve(G);
    const Eigen::Matrix4d H_next = H + Ak.transpose() * H * WinvA;
    const Eigen::Matrix4d G_next = G + Ak * WinvG * Ak.transpose();
    Ak = Ak * WinvA;
    const double change = (H_next - H).cwiseAbs().maxCoeff();
    H = 0.5 * (H_next + H_next.transpose());
    G = 0.5 * (G_next + G_next.transpose());
    if (!H.allFinite()) break;
    if (change <= 1e-13 * H.cwiseAbs().maxCoeff()) break;
  }
  if (!H.allFinite() || iterations >= 100) {
    throw std::runtime_error("ComputePreviewGains: the Riccati equation did not converge (dt " +
                             std::to_string(params.dt) + ", R " + std::to_string(s.R) + ")");
  }

  PreviewGains g;
  g.params = params;
  const double T = params.dt;
  g.A << 1.0, T, T * T / 2.0, 0.0, 1.0, T, 0.0, 0.0, 1.0;
  g.B << T * T * T / 6.0, T * T / 2.0, T;
  g.C << 1.0, 0.0, -params.com_height / params.gravity;
  g.P = H;
  g.doubling_iterations = iterations + 1;
  const double denominator = s.R + s.B.dot(H * s.B);
  const Eigen::RowVector4d K = s.B.transpose() * H * s.A / denominator;  // Δu = -K X
  g.Gi = K[0];
  g.Gx = K.tail<3>();
  // Preview gains (Katayama): Ac = A - B K, X(1) = -Acᵀ P I, G_p(1) = -G_i,
  // G_p(j) = (R + BᵀPB)⁻¹ Bᵀ X(j-1), X(j) = Acᵀ X(j-1).
  const Eigen::Matrix4d Ac_t = (s.A - s.B * K).transpose();
  const int N = params.PreviewSamples();
  g.Gp.resize(N);
  Eigen::Vector4d X = -Ac_t * H.col(0);
  g.Gp[0] = -g.Gi;
  for (int j = 1; j < N; ++j) {
    g.Gp[j] = s.B.dot(X) / denominator;
    X = Ac_t * X;
  }
  return g;
}

double PreviewJerk(const PreviewGains& g, const CartAxis& axis, const double* zmp_reference,
                   int stride) {
  const double e = g.C.dot(axis.x) - zmp_reference[0];
  double preview = 0.0;
  const int N = static_cast<int>(g.Gp.size());
  for (int j = 1; j <= N; ++j) preview += g.Gp[j - 1] * zmp_reference[j * stride];
  return -g.Gi * (axis.error_sum + e) - g.Gx.dot(axis.x) - preview;
}

double PreviewStep(const PreviewGains& g, const double* zmp_reference, int stride, CartAxis* axis) {
  const double u = PreviewJerk(g, *axis, zmp_reference, stride);
  axis->error_sum += g.C.dot(axis->x) - zmp_reference[0];
  axis->x = g.A * axis->x + g.B * u;
  return u;
}

}  // namespace marionette::walk
