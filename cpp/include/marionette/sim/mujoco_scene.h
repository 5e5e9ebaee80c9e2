#pragma once
/// MujocoScene: one MuJoCo 2.2.2 world (robot + objects) and the map between the robot's
/// Pinocchio configuration layout and MuJoCo's qpos/qvel/actuators.
///
/// Conventions (models/README.md): the robot's joints carry the Pinocchio joint names; the base is
///   free_flyer: freejoint `root_joint`   Pinocchio q: x y z qx qy qz qw, v: (v, w) in the base
///   frame
///                                        MuJoCo qpos: x y z qw qx qy qz, qvel: v in world, w in
///                                        base
///   planar:     slides root_x, root_y and hinge root_yaw   Pinocchio q: x y cos sin, v in the base
///   frame fixed:      nothing.
/// Actuators are named like the joint they drive; position servos are MuJoCo `general` actuators
/// with gain kp and bias (0, -kp, -kv), so ctrl = q_des + (kv / kp) v_des tracks (q_des, v_des).
///
/// The floating-base state read here is the simulator's ground truth (a real robot would use an
/// estimator); object poses are ground truth for tests and perturbations only.

#include <mujoco/mujoco.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <functional>
#include <memory>
#include <pinocchio/multibody/model.hpp>
#include <pinocchio/spatial/se3.hpp>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace marionette::sim {

class SimError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A 6D wrench (force, torque) on the robot, world axes, torque about `frame`'s origin.
struct ContactWrench {
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   // [N]
  Eigen::Vector3d torque = Eigen::Vector3d::Zero();  // [N m]
};

class MujocoScene {
 public:
  /// Loads the MJCF scene and maps `robot` (its Pinocchio model, same joint names) onto it.
  /// Throws SimError naming the missing joint/actuator or the MuJoCo load error.
  MujocoScene(const std::string& mjcf_path, const pinocchio::Model& robot);
  ~MujocoScene();
  MujocoScene(const MujocoScene&) = delete;
  MujocoScene& operator=(const MujocoScene&) = delete;

  const mjModel& model() const { return *model_; }
  const mjData& data() const { return *data_; }
  mjData& mutable_data() { return *data_; }
  double timestep() const { return model_->opt.timestep; }
  /// Physics steps per control period `dt` (the model timestep must divide it).
  int SubstepsFor(double dt) const;

  // ---- robot state in Pinocchio layout -------------------------------------------------------
  /// q (nq), v (nv) of the robot from the current MuJoCo state.
  void ReadRobotState(Eigen::Ref<Eigen::VectorXd> q, Eigen::Ref<Eigen::VectorXd> v) const;
  /// Writes q (nq) and v (nv) into MuJoCo (initial state, tests) and recomputes positions.
  void WriteRobotState(const Eigen::VectorXd& q, const Eigen::VectorXd& v);
  /// Actuator force of every actuated dof, in the robot's velocity layout (nv; 0 on the base).
  void ReadJointEfforts(Eigen::Ref<Eigen::VectorXd> effort_v) const;
  /// Sets the position servos to track q_des (nq) and v_des (nv).
  void WriteServoTargets(const Eigen::VectorXd& q_des, const Eigen::VectorXd& v_des);
  /// Encoder calibration (thesis 000 ch. 4): joint `name` reads its MuJoCo position minus
  /// `offset` [rad or m], and every position written to it (state, servo target) gets `offset`
  /// added, so that an encoder known to read q + offset gives the controller q. Replaces the
  /// previous offsets; throws SimError on a joint the robot does not map or a non-finite offset.
  void SetEncoderOffsets(const std::vector<std::pair<std::string, double>>& offsets);

  /// Advances the physics by one control period: mj_step1 then mj_step2 over the substeps.
  /// Call WriteServoTargets between Step1 and Step2 (MuJoCo's split step).
  void Step1();
  void Step2(int substeps);

  // ---- contacts and objects ------------------------------------------------------------------
  /// Sum of the contact wrenches the environment applies to the robot body `body`
  /// (all its geoms), world axes, torque about the body origin. Throws on an unknown body.
  ContactWrench BodyContactWrench(const std::string& body) const;
  ContactWrench BodyContactWrench(int body_id) const;
  int BodyId(const std::string& body) const;  // throws SimError
  /// World pose of a body (ground truth).
  pinocchio::SE3 BodyPose(const std::string& body) const;
  /// Teleports a free body (freejoint) to X_WB with zero velocity (perturbations, tests).
  void SetFreeBodyPose(const std::string& body, const pinocchio::SE3& X_WB);
  /// The same for body `body_id` (which must have a free joint) without recomputing positions:
  /// from a control loop, between two steps (the next mj_step1 recomputes them).
  void MoveFreeBody(int body_id, const pinocchio::SE3& X_WB);

  /// Pushes body `body_id` with `force_W` [N] (world axes, at its centre of mass) for
  /// `duration_s` of simulated time from the next step on: a physical perturbation (a hand
  /// bumping a held object). A new push on a body replaces its previous one; at most
  /// kMaxPushes bodies are pushed at once (throws SimError beyond, or on a non-finite force).
  void Push(int body_id, const Eigen::Vector3d& force_W, double duration_s);
  static constexpr int kMaxPushes = 8;

  /// Moves mocap body `body_id` (a fixture the scene carries, as a cart or a hand would: it
  /// moves whatever forces act on it) to X_WB at constant speed, its orientation by the
  /// shortest rotation, over `duration_s` of simulated time from the next step on (0: at the
  /// next step). A new slide of a body replaces its previous one; at most kMaxSlides bodies
  /// slide at once. Throws SimError for a body that is not a mocap body, or a non-finite or
  /// negative duration.
  void Slide(int body_id, const pinocchio::SE3& X_WB, double duration_s);
  static constexpr int kMaxSlides = 8;

  /// Makes body `body_id`'s geoms slippery or sticky: their sliding friction becomes `mu` and
  /// their priority the scene's highest, so that every contact they make takes their parameters
  /// (MuJoCo's rule: the higher priority geom's condim, friction, solref and solimp; without it
  /// a contact takes the larger friction, the fingers' pads'). Throws SimError for a body
  /// without geoms or a negative or non-finite `mu`.
  void SetFriction(int body_id, double mu);

  /// The simulated grasp (Agimus simulated it too, §3.3.6: physics engines hold objects badly):
  /// activates the weld equality `weld` ("grasp/<robot>/<gripper>/<object>") at the current
  /// relative pose of its two bodies, or releases it. Throws SimError on an unknown weld.
  ///
  /// A release also opens the hand: the geoms of body1's subtree (the gripper and its fingers)
  /// stop colliding until none of them is within reach of body2's geoms (bounding spheres apart),
  /// checked after every step. A real gripper opens before it backs off; a reduced humanoid model
  /// has rigid fingers whose convex hulls fill the jaw, so without this the retreating hand
  /// drags the released object along (6-55 mm in plank-flip trials).
  void SetWeld(int weld_id, bool active);
  /// Releases whose hand is not clear of the object yet (its geoms still do not collide).
  int opening_hands() const { return static_cast<int>(releases_.size()); }
  /// The id of weld equality `name`; throws SimError listing the scene's welds.
  int WeldId(const std::string& name) const;
  bool WeldActive(int weld_id) const { return model_->eq_active[weld_id] != 0; }

  int robot_nq() const { return nq_; }
  int robot_nv() const { return nv_; }
  const std::vector<std::string>& actuated_joint_names() const { return actuated_names_; }

 private:
  struct JointMap {
    int qpos_adr;  // MuJoCo
    int dof_adr;   // MuJoCo
    int idx_q;     // Pinocchio
    int idx_v;     // Pinocchio
    int actuator;  // MuJoCo actuator id or -1
    std::string name;
    double encoder_offset = 0.0;  // subtracted on read, added on write (SetEncoderOffsets)
  };
  enum class Base { kFixed, kFreeFlyer, kPlanar };
  struct Release {  // a released weld whose hand is not clear yet (SetWeld)
    int weld;
    std::vector<int> hand_geoms, object_geoms;
  };
  struct ActivePush {
    int body = -1;
    Eigen::Vector3d force = Eigen::Vector3d::Zero();
    double remaining_s = 0.0;
  };
  struct ActiveSlide {
    int mocap = -1;  // index in mocap_pos / mocap_quat
    Eigen::Vector3d from_p = Eigen::Vector3d::Zero(), to_p = Eigen::Vector3d::Zero();
    Eigen::Quaterniond from_q = Eigen::Quaterniond::Identity();
    Eigen::Quaterniond to_q = Eigen::Quaterniond::Identity();
    double elapsed_s = 0.0, duration_s = 0.0;
  };
  bool SubtreeOf(int body, int root) const;
  void AdvanceSlides(double elapsed_s);
  void EndReleases(const std::function<bool(const Release&)>& ended);  // ends those `ended` says
  void EndClearReleases();

  mjModel* model_ = nullptr;
  mjData* data_ = nullptr;
  Base base_ = Base::kFixed;
  int base_qpos_ = -1, base_dof_ = -1;  // free flyer
  int planar_qpos_[3] = {-1, -1, -1};   // x, y, yaw
  int planar_dof_[3] = {-1, -1, -1};
  int nq_ = 0, nv_ = 0;
  std::vector<JointMap> joints_;
  std::array<ActivePush, kMaxPushes> pushes_{};  // fixed size: no allocation in the loop
  int num_pushes_ = 0;
  std::array<ActiveSlide, kMaxSlides> slides_{};  // fixed size: no allocation in the loop
  int num_slides_ = 0;
  std::vector<std::string> actuated_names_;
  std::vector<Release> releases_;
  // Per geom: the model's own collision masks, and how many releases hold it open (mask 0).
  std::vector<int> own_contype_, own_conaffinity_, open_count_;
};

}  // namespace marionette::sim
