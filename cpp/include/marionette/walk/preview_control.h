#pragma once
/// ZMP preview control on the cart-table model (Kajita 2003; Dang 2012 §2.4.3–2.4.4,
/// eq. 2.50–2.56).
///
/// Per horizontal axis the CoM is a cart of height z_c driven by its jerk u (eq. 2.52–2.54):
///   x(k+1) = A x(k) + B u(k),   x = (c, ċ, c̈),   p(k) = C x(k) = c - (z_c / g) c̈   (the ZMP)
///   A = [1 T T²/2; 0 1 T; 0 0 1],   B = (T³/6, T²/2, T),   C = (1, 0, -z_c/g).
/// The jerk minimises J = Σ Qe e(i)² + Δxᵀ Qx Δx + R Δu(i)² (eq. 2.55, e = p - p_ref) with the
/// reference known N_L samples ahead; the solution is (eq. 2.56)
///   u(k) = -G_i Σ_{i≤k} e(i) - G_x x(k) - Σ_{j=1..N_L} G_p(j) p_ref(k+j).
/// The gains come from the discrete algebraic Riccati equation of the error system augmented
/// with the integral of e (Katayama 1985), solved here by the structured doubling algorithm.
///
/// Model (gains, immutable) and state (per axis, owned by the caller) are split: the
/// PatternGenerator entity keeps the state in a state signal.

#include <Eigen/Core>

namespace marionette::walk {

/// Parameters of the preview controller. Lengths in metres, times in seconds.
struct PreviewControlParams {
  double dt = 1e-3;           ///< T, the sampling period [s] (the controller tick)
  double com_height = 0.814;  ///< z_c, CoM height above the ground [m]
  double gravity = 9.81;      ///< g [m/s²]
  double preview_time = 1.6;  ///< N_L T [s] (Dang fig. 2.14: 1.6 s tracks, 0.8 s does not)
  double qe = 1.0;            ///< Qe, weight of the ZMP error
  /// R, weight of the jerk increment; <= 0 selects Kajita's R = 1e-6 at T = 5 ms scaled to T so
  /// that the continuous-time trade-off is the same: Δu ≈ u̇ T, hence R T² is kept constant.
  double r = 0.0;
  /// Throws std::invalid_argument naming the bad field.
  void Check() const;
  /// R actually used.
  double EffectiveR() const;
  /// N_L, the number of previewed samples.
  int PreviewSamples() const;
};

/// A, B, C and the gains of eq. 2.56, with what they came from.
struct PreviewGains {
  PreviewControlParams params;
  Eigen::Matrix3d A;
  Eigen::Vector3d B;
  Eigen::RowVector3d C;
  double Gi = 0.0;              ///< integral gain
  Eigen::RowVector3d Gx;        ///< state gain
  Eigen::VectorXd Gp;           ///< (N_L) preview gains, Gp[j-1] = G_p(j)
  Eigen::Matrix4d P;            ///< solution of the augmented DARE
  int doubling_iterations = 0;  ///< how many doubling steps the DARE took
};

/// Solves the augmented DARE and builds the gains (eq. 2.56). Costs O(N_L) after the DARE; call
/// off the control loop. Throws std::invalid_argument on bad parameters, std::runtime_error if
/// the DARE does not converge.
PreviewGains ComputePreviewGains(const PreviewControlParams& params);

/// The augmented system of Katayama's error formulation (state (Σe-increment, Δx), 4 x 4), as
/// used by ComputePreviewGains; exposed for tests.
struct AugmentedSystem {
  Eigen::Matrix4d A;  ///< [1 CA; 0 A]
  Eigen::Vector4d B;  ///< [CB; B]
  Eigen::Matrix4d Q;  ///< diag(Qe, Qx = 0)
  double R = 0.0;
};
AugmentedSystem MakeAugmentedSystem(const PreviewControlParams& params);

/// Residual ‖P - (AᵀPA - AᵀPB (R + BᵀPB)⁻¹ BᵀPA + Q)‖_max of a candidate DARE solution.
double RiccatiResidual(const AugmentedSystem& sys, const Eigen::Matrix4d& P);

/// One axis of the cart: x = (c, ċ, c̈) and the running sum Σ e(i) of the ZMP error.
struct CartAxis {
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  double error_sum = 0.0;
};

/// The jerk u(k) of eq. 2.56 for one axis. `zmp_reference` holds p_ref(k), p_ref(k+1), ...,
/// p_ref(k+N_L) (N_L + 1 values, strided: element j at zmp_reference[j * stride]); `axis` is
/// x(k) and Σ_{i<k} e(i). Allocates nothing.
double PreviewJerk(const PreviewGains& gains, const CartAxis& axis, const double* zmp_reference,
                   int stride = 1);

/// Advances one axis by one period under the jerk of eq. 2.56: adds e(k) to the sum and
/// integrates x(k+1) = A x(k) + B u(k). Returns u(k).
double PreviewStep(const PreviewGains& gains, const double* zmp_reference, int stride,
                   CartAxis* axis);

}  // namespace marionette::walk
