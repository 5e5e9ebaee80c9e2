#pragma once
/// The robot model and the kinematics of one tick, shared by every consumer.
///
/// `Kinematics` holds the result of ONE Pinocchio pass at a configuration q: joint placements,
/// frame placements X_WF, joint Jacobians (world), centre of mass c_W and its Jacobian. The
/// RobotModel entity computes it once per tick; features read it (frame Jacobians are then a
/// cheap change of frame of a few columns, see LocalFrameJacobian).
///
/// Notation (STYLE.md rule 6): X_AB is the pose of frame B in frame A, p_AB_A the position of B
/// from A expressed in A, v (nv) a tangent vector of the configuration space, q (nq) a
/// configuration. Twists are (linear; angular), Pinocchio's order.

#include <Eigen/Core>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <pinocchio/multibody.hpp>

#include "marionette/graph/value_traits.h"

namespace marionette::sot {

/// Raised for every invalid argument of the sot layer; the message names the entity and the
/// offending value (unknown frame, wrong size, bad gain ...).
class SotError : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

using ModelPtr = std::shared_ptr<const pinocchio::Model>;
using Matrix6Xd = Eigen::Matrix<double, 6, Eigen::Dynamic>;

/// How the robot is attached to the world.
enum class BaseJoint {
  kFixed,      ///< industrial arm: q = joint angles
  kFreeFlyer,  ///< humanoid: q = (x y z qx qy qz qw, joints), v = (v_B, w_B, joints)
  kPlanar,     ///< mobile base: q = (x y cos(yaw) sin(yaw), joints)
};

/// Parses "fixed" | "free_flyer" | "planar" (the names of marionette.robots); throws SotError.
BaseJoint ParseBaseJoint(const std::string& name);

/// Loads a URDF with the given base. When `srdf_path` is not empty, its reference configurations
/// (e.g. a humanoid's "half_sitting") are loaded into model->referenceConfigurations. Throws
/// SotError when a file cannot be read.
ModelPtr LoadModel(const std::string& urdf_path, BaseJoint base, const std::string& srdf_path = "");

/// The example-robot-data `robots/` folder: $MARIONETTE_ROBOT_DATA_DIR if set, else the folder of
/// the example-robot-data package found at build time.
std::string ExampleRobotDataDir();

/// A frame a feature controls, resolved once at construction.
struct FrameRef {
  std::string name;
  pinocchio::FrameIndex frame = 0;
  pinocchio::JointIndex joint = 0;  ///< parent joint
  std::vector<int> columns;         ///< tangent indices (v) of the joints that move the frame
};

/// Resolves `frame_name` in `model`; throws SotError naming `who` and listing similar frame names
/// when it does not exist.
FrameRef MakeFrameRef(const pinocchio::Model& model, const std::string& frame_name,
                      const std::string& who);

/// The kinematics of one configuration (one Pinocchio pass).
class Kinematics {
 public:
  /// Computed at the model's neutral configuration.
  explicit Kinematics(ModelPtr model);

  /// One pass at q (nq): forward kinematics, frame placements, joint Jacobians, centre of mass
  /// and its Jacobian (no subtree CoMs). Allocates nothing.
  void Compute(const Eigen::Ref<const Eigen::VectorXd>& q);

  const pinocchio::Model& model() const { return *model_; }
  const ModelPtr& model_ptr() const { return model_; }
  const pinocchio::Data& data() const { return data_; }
  const Eigen::VectorXd& q() const { return q_; }  ///< (nq) configuration of this pass
  /// X_WF of a frame.
  const pinocchio::SE3& placement(const FrameRef& f) const { return data_.oMf[f.frame]; }
  /// c_W, centre of mass in world (3).
  Eigen::Vector3d com() const { return data_.com[0]; }
  /// dc_W/dq (3 x nv).
  const pinocchio::Data::Matrix3x& com_jacobian() const { return data_.Jcom; }

 private:
  ModelPtr model_;
  pinocchio::Data data_;
  Eigen::VectorXd q_;
};

/// J_F (6 x nv), the Jacobian of frame F expressed in F (Pinocchio LOCAL: body twist (v_F, w_F)
/// = J_F v). Writes only the columns in f.columns: the others must already be zero (allocate J
/// zeroed once; they never change).
void LocalFrameJacobian(const Kinematics& kinematics, const FrameRef& f, Eigen::Ref<Matrix6Xd> J_F);

/// Selected components of a feature: mask[i] keeps component i. Empty = keep all.
using Mask = std::vector<bool>;
/// The kept indices of a mask over `full_dimension` components; throws SotError (naming `who`)
/// on a wrong size or when nothing is kept.
std::vector<int> MaskIndices(const Mask& mask, int full_dimension, const std::string& who);

}  // namespace marionette::sot

namespace marionette::graph {

/// A Kinematics flows through the graph like any signal. It flattens to the configuration q it
/// was computed at (nq x 1); unflattening a q recomputes the whole pass (so a feature's
/// kinematics input can be set from Python with a configuration).
template <>
struct ValueTraits<sot::Kinematics> {
  static constexpr const char* kName = "kinematics";
  static Shape ShapeOf(const sot::Kinematics& k) { return {static_cast<int>(k.q().size()), 1}; }
  static void Flatten(const sot::Kinematics& k, double* out) {
    Eigen::Map<Eigen::VectorXd>(out, k.q().size()) = k.q();
  }
  static void Unflatten(const double* in, sot::Kinematics* k) {
    k->Compute(Eigen::Map<const Eigen::VectorXd>(in, k->q().size()));
  }
  static bool IsFinite(const sot::Kinematics& k) { return k.q().allFinite(); }
};

}  // namespace marionette::graph
