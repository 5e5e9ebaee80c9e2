// Preview control (Dang 2012 eq. 2.52–2.56): the Riccati solution against plain iteration, the
// preview law against a brute-force batch least-squares optimum, and the ZMP tracking of a
// walking reference with 1.6 s and 0.8 s of preview (fig. 2.14–2.15).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <vector>

#include "marionette/walk/preview_control.h"

namespace marionette::walk {
namespace {

PreviewControlParams Kajita(double preview_time = 1.6) {
  PreviewControlParams p;  // fig. 2.13: T = 5 ms, z_c = 0.814 m, Qe = 1, R = 1e-6
  p.dt = 5e-3;
  p.com_height = 0.814;
  p.preview_time = preview_time;
  p.qe = 1.0;
  p.r = 1e-6;
  return p;
}

// The ZMP reference of fig. 2.14: standing 2 s (longer than the preview: the walk enters the
// window from its far end, as the footstep manager's start delay arranges), then steps of 0.8 s
// (0.2 s of transfer) of 0.3 m forward alternating ±0.1 m sideways, then standing again. Returns
// (x, y) at time t.
Eigen::Vector2d WalkReference(double t) {
  const double start = 2.0, period = 0.8, transfer = 0.2;
  const int steps = 6;
  const auto support = [&](int i) {  // i = 0 .. steps-1
    return Eigen::Vector2d(0.3 * i, i % 2 == 0 ? 0.1 : -0.1);
  };
  const Eigen::Vector2d rest(0.0, 0.0), end(0.3 * (steps - 1), 0.0);
  if (t < start) return rest;
  const int i = static_cast<int>((t - start) / period);
  const double tau = t - start - i * period;
  const Eigen::Vector2d from = i == 0 ? rest : i <= steps ? support(i - 1) : end;
  const Eigen::Vector2d to = i < steps ? support(i) : end;
  return tau < transfer ? from + (to - from) * (tau / transfer) : to;
}

TEST(PreviewControlTest, DoublingSolvesTheRiccatiEquationLikePlainIteration) {
  const PreviewControlParams params = Kajita();
  const PreviewGains g = ComputePreviewGains(params);
  const AugmentedSystem s = MakeAugmentedSystem(params);
  EXPECT_LT(RiccatiResidual(s, g.P), 1e-9 * g.P.cwiseAbs().maxCoeff());
  EXPECT_LT(g.doubling_iterations, 40);
  // Independent: the Riccati recursion P ← Q + AᵀPA − AᵀPB (R + BᵀPB)⁻¹ BᵀPA until it stops moving.
  Eigen::Matrix4d P = s.Q;
  for (int i = 0; i < 200000; ++i) {
    const Eigen::RowVector4d BtPA = s.B.transpose() * P * s.A;
    const Eigen::Matrix4d next =
        s.Q + s.A.transpose() * P * s.A - BtPA.transpose() * BtPA / (s.R + s.B.dot(P * s.B));
    const double change = (next - P).cwiseAbs().maxCoeff();
    P = next;
    if (change < 1e-14 * P.cwiseAbs().maxCoeff()) break;
  }
  EXPECT_LT((P - g.P).cwiseAbs().maxCoeff(), 1e-7 * P.cwiseAbs().maxCoeff());
  // The closed loop is stable, and the preview gains fade out within the 1.6 s window (fig. 2.13).
  const Eigen::RowVector4d K = s.B.transpose() * g.P * s.A / (s.R + s.B.dot(g.P * s.B));
  const Eigen::Matrix4d Ac = s.A - s.B * K;
  EXPECT_LT(Ac.eigenvalues().cwiseAbs().maxCoeff(), 1.0);
  EXPECT_EQ(g.Gp.size(), 320);
  EXPECT_LT(std::abs(g.Gp[g.Gp.size() - 1]), 0.01 * g.Gp.cwiseAbs().maxCoeff());
}

TEST(PreviewControlTest, RejectsBadParametersWithTheField) {
  PreviewControlParams p;
  p.com_height = -1.0;
  try {
    ComputePreviewGains(p);
    FAIL() << "no exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("com_height"), std::string::npos) << e.what();
  }
  p = PreviewControlParams{};
  p.dt = 0.0;
  EXPECT_THROW(ComputePreviewGains(p), std::invalid_argument);
}

// Brute force: from the state reached at tick k0, the jerk sequence minimising
//   Σ_{i=1..H} Qe e(i)² + R (u(i−1) − u(i−2))²   (u(−1) the last applied jerk)
// with the reference held after the preview window (the law's assumption) is a linear least-
// squares problem; its first jerk must be the law's u(k0).
TEST(PreviewControlTest, PreviewLawIsTheBatchOptimum) {
  const PreviewControlParams params = Kajita();
  const PreviewGains g = ComputePreviewGains(params);
  const int N = params.PreviewSamples(), H = N + 700;
  const double T = params.dt;
  const auto reference = [&](int k) { return WalkReference(k * T).y(); };
  std::vector<double> window(N + 1);
  CartAxis axis;
  double u_previous = 0.0, u_law = 0.0;
  const int k0 = static_cast<int>(2.5 / T);  // in the first step: everything is moving
  for (int k = 0; k <= k0; ++k) {
    for (int j = 0; j <= N; ++j) window[j] = reference(k + j);
    if (k == k0) {
      u_law = PreviewJerk(g, axis, window.data());
      break;
    }
    u_previous = PreviewStep(g, window.data(), 1, &axis);
  }
  // e(i) = C A^i x0 + Σ_{m<i} C A^{i−1−m} B u(m) − p_ref(k0 + i), i = 1..H.
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(2 * H, H);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(2 * H);
  std::vector<double> markov(H);  // C A^n B
  Eigen::Vector3d AnB = g.B;
  for (int n = 0; n < H; ++n, AnB = g.A * AnB) markov[n] = g.C.dot(AnB);
  Eigen::Vector3d Aix = axis.x;
  const double sqrt_qe = std::sqrt(params.qe), sqrt_r = std::sqrt(params.EffectiveR());
  for (int i = 1; i <= H; ++i) {
    Aix = g.A * Aix;
    for (int m = 0; m < i; ++m) M(i - 1, m) = sqrt_qe * markov[i - 1 - m];
    rhs[i - 1] = sqrt_qe * (reference(k0 + std::min(i, N)) - g.C.dot(Aix));
  }
  for (int i = 0; i < H; ++i) {
    M(H + i, i) = sqrt_r;
    if (i > 0) M(H + i, i - 1) = -sqrt_r;
  }
  rhs[H] = sqrt_r * u_previous;
  const Eigen::VectorXd u = M.colPivHouseholderQr().solve(rhs);
  EXPECT_NEAR(u[0], u_law, 1e-4 * std::max(1.0, std::abs(u_law)))
      << "law " << u_law << ", batch " << u[0];
  EXPECT_GT(std::abs(u_law - u_previous), 1e-3);  // the comparison is not between two zeros
}

struct Tracking {
  double max_error = 0.0;    // max |p − p_ref| during the walk [m]
  double final_error = 0.0;  // |c − p_ref| at the end [m]
};

Tracking Track(const PreviewControlParams& params) {
  const PreviewGains g = ComputePreviewGains(params);
  const int N = params.PreviewSamples();
  const double T = params.dt;
  std::vector<double> wx(N + 1), wy(N + 1);
  CartAxis x, y;
  Tracking result;
  const int end = static_cast<int>(10.0 / T);
  for (int k = 0; k < end; ++k) {
    for (int j = 0; j <= N; ++j) {
      const Eigen::Vector2d p = WalkReference((k + j) * T);
      wx[j] = p.x(), wy[j] = p.y();
    }
    const Eigen::Vector2d p(g.C.dot(x.x), g.C.dot(y.x));
    result.max_error = std::max(result.max_error, (p - Eigen::Vector2d(wx[0], wy[0])).norm());
    PreviewStep(g, wx.data(), 1, &x);
    PreviewStep(g, wy.data(), 1, &y);
  }
  result.final_error = (Eigen::Vector2d(x.x[0], y.x[0]) - WalkReference(end * T)).norm();
  return result;
}

TEST(PreviewControlTest, ZmpTracksTheWalkWithTheLongPreviewNotTheShortOne) {
  // Fig. 2.14: with 1.6 s of preview the ZMP follows the stair-like reference; fig. 2.15: with
  // 0.8 s it leaves it. The lateral swing is ±0.1 m: errors are compared to that.
  const Tracking long_preview = Track(Kajita(1.6));
  const Tracking short_preview = Track(Kajita(0.8));
  std::printf("max ZMP error: %.1f mm with 1.6 s preview, %.1f mm with 0.8 s\n",
              1e3 * long_preview.max_error, 1e3 * short_preview.max_error);
  EXPECT_LT(long_preview.max_error, 0.01);
  EXPECT_GT(short_preview.max_error, 2.0 * long_preview.max_error);
  EXPECT_LT(long_preview.final_error, 1e-3);  // and the CoM comes to rest over the final ZMP
}

TEST(PreviewControlTest, OneMillisecondGainsTrackLikeKajitasFiveMilliseconds) {
  PreviewControlParams fast = Kajita(1.6);
  fast.dt = 1e-3;
  fast.r = 0.0;  // R scaled with T² (see PreviewControlParams::r)
  const Tracking at_1ms = Track(fast), at_5ms = Track(Kajita(1.6));
  std::printf("max ZMP error: %.2f mm at 1 ms, %.2f mm at 5 ms\n", 1e3 * at_1ms.max_error,
              1e3 * at_5ms.max_error);
  EXPECT_LT(at_1ms.max_error, 0.01);
  EXPECT_NEAR(at_1ms.max_error, at_5ms.max_error, 0.5 * at_5ms.max_error);
}

}  // namespace
}  // namespace marionette::walk
