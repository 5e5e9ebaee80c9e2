#pragma once
/// Gaze: keeps the image of a world point at a desired image point (default: the image centre)
/// through the point interaction matrix (Chaumette & Hutchinson 2006; Nicolin 2022 §5.2.2 IBVS).
/// Camera frame C is an optical frame (z along the view, x right, y down).
///   p_C = R_WC^T (P_W - p_WC) = (X, Y, Z),   s = (X/Z, Y/Z) normalised image coordinates
///   e   = s - s*
///   J   = L_p [-I3, [p_C]x] J_C,  L_p = ∂s/∂p_C = [[1/Z, 0, -X/Z²], [0, 1/Z, -Y/Z²]]
///   ∂e/∂t = L_p R_WC^T Ṗ_W
/// Z is floored at 1 cm so a point behind the camera keeps a finite (meaningless) error.
/// @entity  inputs: kinematics, target (3, P_W), desired (2, default 0 = centre),
///          target_velocity (3, default 0)   outputs: terms, error (x, y), jacobian

#include "marionette/sot/feature.h"

namespace marionette::sot {

class FeatureGaze final : public Feature {
 public:
  FeatureGaze(std::string name, ModelPtr model, const std::string& camera_frame,
              const Mask& mask = {});
  const char* type_name() const override { return "FeatureGaze"; }
  graph::InputSignal<Eigen::VectorXd>& target_input() { return *target_; }
  graph::InputSignal<Eigen::VectorXd>& desired_input() { return *desired_; }
  graph::InputSignal<Eigen::VectorXd>& target_velocity_input() { return *target_velocity_; }

 private:
  void ComputeFull(const graph::Tick& t, const Kinematics& kinematics,
                   FeatureTerms* full) const override;

  FrameRef camera_;
  graph::InputSignal<Eigen::VectorXd>* target_{};
  graph::InputSignal<Eigen::VectorXd>* desired_{};
  graph::InputSignal<Eigen::VectorXd>* target_velocity_{};
  mutable Matrix6Xd J_C_;
};

}  // namespace marionette::sot
