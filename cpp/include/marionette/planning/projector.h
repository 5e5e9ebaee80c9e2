// Newton-Raphson projection onto numerical constraints (thesis 000 Algorithm 1, §3.2.2; HPP
// hpp-constraints' HierarchicalIterative solver with explicit substitution).
// C++ twin of marionette.planning.projector.Projector.project: the Python side compiles the
// constraints (substitution order, merged placements, free variables, bounds) and hands the
// result over; this side runs the same Newton loop (same step-size schedule, iteration limit,
// priorities, bounds, saturation and failure reasons) without Python per-iteration overhead.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>
#include <pinocchio/spatial/se3.hpp>

namespace marionette::planning {

/// Why a projection stopped; values match marionette.planning.projector.ProjectionStatus.
enum class ProjectionStatus {
  kSuccess = 0,
  kMaxIterations,
  kNotDecreasing,
  kLocalMinimum,
  kNotFinite
};

struct ProjectionOutcome {
  ProjectionStatus status = ProjectionStatus::kSuccess;
  int iterations = 0;
  double error_norm = 0.0;
};

/// An object surface on an environment surface (Python constraints.Placement): the candidate
/// pairs, each a relative transformation F_E (joint_e, M_env) -> F_O (joint_o, M_obj flipped, z
/// into the object), and the convex polygon of the environment surface (k x 2, counter-clockwise).
struct PlacementSpec {
  std::vector<int> joint_e, joint_o;
  std::vector<pinocchio::SE3> M_env, M_obj;
  std::vector<Eigen::MatrixX2d> polygons;
  double margin = 0.0;
  bool select = false;  // pair chosen at the start of each projection (no complement pins it)
};

/// One implicit constraint.  kind: kRelative (joint1, M1, joint2, M2, mask), kPlacement and
/// kComplement (placement: index in the placement list), kLocked (implicit locked joint:
/// idx_q, idx_v, nq of the joint; its value is passed with the right-hand sides), kCom (centre
/// of mass of the whole model expressed in the frame F = oMi[joint1] M1, on the rows x y z
/// selected by mask[0..2]: e = (X_WF^-1 c)[mask] - rhs; Python constraints.ComPosition).
struct ImplicitSpec {
  enum class Kind { kRelative, kPlacement, kComplement, kLocked, kCom };
  Kind kind = Kind::kRelative;
  int level = 0;
  int joint1 = 0, joint2 = 0;
  pinocchio::SE3 M1 = pinocchio::SE3::Identity(), M2 = pinocchio::SE3::Identity();
  Eigen::Array<bool, 6, 1> mask = Eigen::Array<bool, 6, 1>::Constant(true);
  int placement = -1;
  int idx_q = 0, idx_v = 0, nq = 0;
};

/// Step-size schedule (Python projector.LineSearch).
struct LineSearchSpec {
  enum class Kind { kFixedSequence, kErrorNorm, kConstant };
  Kind kind = Kind::kConstant;
  double alpha0 = 0.1, alpha_max = 0.95, K = 0.8, alpha_min = 0.2;
  double max_step = 1.0;  // bound on |dq| of one iteration (inf: none)
};

/// Everything Projector._compile decides, in Pinocchio's index spaces.
struct ProjectorSpec {
  std::vector<ImplicitSpec> implicit;  // in level order (level 0 first)
  std::vector<PlacementSpec> placements;
  std::vector<int> locked_idx_q, locked_nq;  // explicit locked joints, substituted first
  std::vector<int> relative_idx_q, relative_parent, relative_output;
  std::vector<pinocchio::SE3> relative_M_PO;  // X_WO = oMi[parent] M_PO
  bool patchable = false;                     // outputs are leaf free-flyers under the universe
  std::vector<int> static_joints;             // locked leaves: their Jacobian reads as 0
  std::vector<int> free_idx;                  // free velocity variables
  std::vector<int> bounded_idx_q;             // q entries clamped to [lower, upper]
  Eigen::VectorXd lower, upper;               // (bounded)
  std::vector<int> sat_k, sat_q;              // 1-dof joints: free column, q index
  Eigen::VectorXd sat_lo, sat_hi;
  LineSearchSpec line_search;
  double damping = 1e-8;
};

/// The projector.  One instance per thread (it owns its Pinocchio data).
class Projector {
 public:
  /// Throws std::invalid_argument on indices out of the model or inconsistent sizes.
  Projector(pinocchio::Model model, ProjectorSpec spec);

  /// Size of the packed right-hand side Project reads: every implicit constraint's rhs in
  /// spec order, then the explicit locked values, then the implicit locked joints' values.
  int rhs_size() const { return rhs_size_; }
  int num_placements() const { return static_cast<int>(spec_.placements.size()); }

  /// Projects q (nq, in place).  rhs: see rhs_size; pairs (one per placement): the current
  /// surface pair, updated for the placements that select theirs.
  ProjectionOutcome Project(Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
                            std::vector<int>* pairs, double error_threshold, int max_iterations);

  /// Does q satisfy every constraint within threshold (Python Projector.is_satisfied): the
  /// explicit ones (locked values, quaternions sign-insensitive; attached poses, |log6|) and
  /// the implicit ones (|e| at q as it is, no substitution)?  Placements that select their
  /// surface pair select it at q (written to pairs).
  bool IsSatisfied(const Eigen::Ref<const Eigen::VectorXd>& q, const Eigen::VectorXd& rhs,
                   std::vector<int>* pairs, double threshold);

  /// Stacked implicit errors at q without substitution (Python's Projector.error, for tests).
  Eigen::VectorXd Error(Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
                        std::vector<int>* pairs);
  /// Stacked implicit Jacobian (size x nv, before the chain rule and column selection) at q
  /// after substitution (for the finite-difference tests).
  Eigen::MatrixXd Jacobian(Eigen::Ref<Eigen::VectorXd> q, const Eigen::VectorXd& rhs,
                           std::vector<int>* pairs);

  const pinocchio::Model& model() const { return model_; }
  int size() const { return size_; }

 private:
  struct Relative {  // cached relative pose of one constraint at the current configuration
    pinocchio::SE3 oMi1, X2, M;
    Eigen::Matrix<double, 6, 1> v6;
  };
  void SetRhs(const Eigen::VectorXd& rhs, const std::vector<int>& pairs);
  void UpdateAndSubstitute(Eigen::Ref<Eigen::VectorXd> q);
  void ApplyExplicit(Eigen::Ref<Eigen::VectorXd> q);
  void SelectPairs();
  const Eigen::Matrix<double, 6, Eigen::Dynamic>& JointJacobian(int joint);
  void RelativePose(int joint1, const pinocchio::SE3& M1, int joint2, const pinocchio::SE3& M2,
                    Relative* out) const;
  void RelativeJacobian(int joint1, int joint2, const pinocchio::SE3& M2, const Relative& rel,
                        Eigen::Matrix<double, 6, Eigen::Dynamic>* J);
  void Errors(int level, Eigen::VectorXd* e);
  void Jacobians(int level, Eigen::MatrixXd* J);
  void Descent(const Eigen::Ref<const Eigen::VectorXd>& q, Eigen::VectorXd* step);

  // Centre of mass (and its Jacobian, world frame, 3 x nv) at q_cur_, computed on first use
  // after each update in their own Pinocchio data.
  const Eigen::Vector3d& Com();
  const Eigen::Matrix3Xd& ComJacobian();

  pinocchio::Model model_;
  pinocchio::Data data_;
  pinocchio::Data com_data_;
  bool com_valid_ = false, com_jacobian_valid_ = false;
  ProjectorSpec spec_;
  int rhs_size_ = 0, size_ = 0;
  std::vector<int> level_begin_;  // constraint index range of each level
  std::vector<int> level_rows_;
  std::vector<int> rhs_offset_;             // per implicit constraint
  std::vector<int> locked_value_offset_;    // per explicit locked joint
  std::vector<int> implicit_value_offset_;  // per implicit constraint (kLocked only)
  std::vector<int> sizes_;                  // rows of each implicit constraint
  Eigen::VectorXd rhs_;
  std::vector<int> pair_;
  std::vector<char> is_static_, is_root_ff_;
  std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic>> jac_;
  std::vector<char> jac_valid_;
  std::vector<pinocchio::SE3::ActionMatrixType> Ad_OP_;
  Eigen::Matrix<double, 6, Eigen::Dynamic> J6_, Jtmp_;
  std::vector<Eigen::VectorXd> errors_;
  std::vector<Eigen::MatrixXd> jacobians_;
  Eigen::VectorXd dv_, step_, q_cur_;
  bool clipped_ = true;
  bool all_free_ = true;
};

}  // namespace marionette::planning
