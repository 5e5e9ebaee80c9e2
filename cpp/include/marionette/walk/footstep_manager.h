#pragma once
/// FootstepManager: holds the footstep plan and turns it into the references of a walk
/// (Dang 2012 §2.6.3, fig. 2.27: it "stocks the stepping plan given by the planner and updates
/// it to the pattern generator in a timely manner").
///
/// Plans arrive from another thread through a lock-free mailbox (Post); the poll hook applies
/// them at the start of a tick to the steps that have not started: the step in progress (from
/// the start of its double support to its landing) is never changed, steps after it are
/// replaced from the plan's first_step_index on. With no step in progress or queued, a plan is
/// taken whole whatever its indices (a new walk).
///
/// Timeline (times from the tick clock): standing → for each step, double support (the ZMP
/// reference moves onto the foot that stays, quintic blend) then single support (ZMP on that
/// foot, the other swings, swing_foot.h) → a final double support moving the ZMP to the middle
/// of the feet → standing. The first step after standing gets at least
/// `min_first_double_support`, so the CoM can start towards the first support foot, and starts
/// `start_delay` after the plan arrived (the step is locked from then on).
///
/// @entity  inputs: none (plans through Post)
///          outputs: left_foot, right_foot (SE3 sole references X_WF),
///                   left_foot_velocity, right_foot_velocity (6: linear of the sole origin,
///                   angular; world axes — FeatureSE3's reference_velocity),
///                   waist (SE3: turning with the feet's mean yaw, as it stood at the start —
///                   HoldWaist —, at the feet's midpoint), waist_velocity (6: the yaw rate,
///                   half the swinging foot's),
///                   zmp_window (2 x (N+1): ZMP reference at t, t+dt, ..., t+N dt, world [m]),
///                   zmp_reference (2, at t), phase (int, WalkPhase), phase_progress (0..1),
///                   step_index (int, step in progress, -1 when none), support (int: 1 left,
///                   2 right, 3 both feet on the ground), plan_id (int, last plan applied)

#include <Eigen/Core>
#include <array>
#include <atomic>
#include <cstdint>
#include <string>

#include "marionette/graph/entity.h"
#include "marionette/runtime/spsc_queue.h"
#include "marionette/walk/footstep_plan.h"

namespace marionette::walk {

enum class WalkPhase : int { kStanding = 0, kDoubleSupport = 1, kLeftSwing = 2, kRightSwing = 3 };
/// "standing" | "double_support" | "left_swing" | "right_swing" (lcmt_walk_status.phase).
const char* ToString(WalkPhase phase);

struct FootstepManagerOptions {
  double dt = 1e-3;            ///< [s] tick period, the spacing of zmp_window samples
  int preview_samples = 1600;  ///< N (1.6 s at 1 kHz, Dang fig. 2.14)
  double final_double_support =
      1.0;  ///< [s] ZMP back to the middle of the feet after the last step
  double min_first_double_support = 0.6;  ///< [s] at least this before the first step from standing
  /// [s] a walk from standing starts this long after its plan arrives, the ZMP reference held
  /// meanwhile, so that the pattern generator sees the first move enter at the far end of its
  /// window (where the preview gains are ~1 % of their peak) instead of reacting to it at once
  /// with a jerk spike; < 0 = the preview time (N dt).
  double start_delay = -1.0;
  double StartDelay() const { return start_delay < 0.0 ? preview_samples * dt : start_delay; }
  int mailbox_capacity = 4;  ///< plans in flight between Post and the next tick
  void Check() const;        ///< throws std::invalid_argument
};

class FootstepManager final : public graph::Entity {
 public:
  static constexpr int kLeft = 0, kRight = 1;
  /// Standing on `left` and `right` (sole placements) with the ZMP reference at `rest_zmp`
  /// (e.g. the CoM's ground projection, so that a pattern generator starts at rest).
  FootstepManager(std::string name, const FootPlacement& left, const FootPlacement& right,
                  const Eigen::Vector2d& rest_zmp, FootstepManagerOptions options = {});
  const char* type_name() const override { return "FootstepManager"; }

  /// Any one thread (the single producer): queues `plan` for the next tick. Returns false when
  /// the mailbox is full (the plan is dropped). Validate it first (ValidateFootstepPlan).
  bool Post(const FootstepPlan& plan);
  /// Loop thread, between ticks: standing on these feet, ZMP reference at `rest_zmp`, queue
  /// emptied (plans in the mailbox stay). No allocation.
  void Reset(const FootPlacement& left, const FootPlacement& right,
             const Eigen::Vector2d& rest_zmp);
  /// Loop thread, between ticks, after Reset: the waist's orientation now (world). The waist
  /// reference keeps it relative to the feet's mean yaw for the whole walk: the walk starts
  /// where the robot stands (a standing pelvis pitched a third of a degree from upright, at
  /// 20/s, was a refused 0.12 rad/s start) and still turns with the feet.
  void HoldWaist(const Eigen::Matrix3d& R_waist);
  /// Loop thread, between ticks: the walk ends with the step in progress (it is never changed)
  /// — queued steps after it are dropped, the final double support then brings the ZMP to the
  /// middle of the feet — and every later plan is refused (counted) until Reset. No allocation.
  /// What a hold controller does to stop a walking robot safely (controller/hold_controller.h).
  void StopAfterCurrentStep();
  bool stopped() const { return stopped_; }

  /// Plans applied and refused (a gap between the queue's last index and the plan's first).
  int64_t applied_plans() const { return applied_plans_; }
  int64_t refused_plans() const { return refused_plans_; }
  int64_t dropped_plans() const { return dropped_plans_.load(); }
  /// Loop thread: the source_hash of the plans the last poll took in (at most 8 per tick).
  int drained_count() const { return drained_count_; }
  int64_t drained_hash(int i) const { return drained_hashes_[i]; }
  /// Steps completed since construction.
  int64_t completed_steps() const { return completed_steps_; }
  /// The queued steps (front = in progress when walking); valid between ticks.
  int num_queued() const { return queue_size_; }
  const Footstep& queued(int k) const { return queue_[k]; }
  /// Planted placement of a foot (kLeft / kRight) as of the last landing.
  const FootPlacement& planted(int side) const { return feet_[side]; }
  const FootstepManagerOptions& options() const { return options_; }

  graph::OutputSignal<pinocchio::SE3>& left_foot_output() { return *left_foot_; }
  graph::OutputSignal<pinocchio::SE3>& right_foot_output() { return *right_foot_; }
  graph::OutputSignal<Eigen::VectorXd>& left_foot_velocity_output() { return *left_velocity_; }
  graph::OutputSignal<Eigen::VectorXd>& right_foot_velocity_output() { return *right_velocity_; }
  /// The waist's orientation reference: the trunk turns with the feet. Left free, its yaw
  /// swung 10° with a long stride and the walk diverged laterally two steps later (step-over).
  graph::OutputSignal<pinocchio::SE3>& waist_output() { return *waist_; }
  graph::OutputSignal<Eigen::VectorXd>& waist_velocity_output() { return *waist_velocity_; }
  graph::OutputSignal<Eigen::MatrixXd>& zmp_window_output() { return *zmp_window_; }
  graph::OutputSignal<Eigen::VectorXd>& zmp_reference_output() { return *zmp_reference_; }
  graph::OutputSignal<int>& phase_output() { return *phase_; }
  graph::OutputSignal<double>& phase_progress_output() { return *phase_progress_; }
  graph::OutputSignal<int>& step_index_output() { return *step_index_; }
  graph::OutputSignal<int>& support_output() { return *support_; }
  graph::OutputSignal<int>& plan_id_output() { return *plan_id_; }

 private:
  enum class Mode { kStanding, kWalking, kStopping };
  // One piece of the ZMP reference: from p0 at t0 to p1 at t1 (quintic blend; p0 == p1 when flat).
  struct ZmpSegment {
    double t0 = 0.0, t1 = 0.0;
    Eigen::Vector2d p0 = Eigen::Vector2d::Zero(), p1 = Eigen::Vector2d::Zero();
  };
  static constexpr int kMaxSegments = 2 * FootstepPlan::kMaxSteps + 2;

  void Poll(const graph::Tick& t);
  void ApplyPlan(const FootstepPlan& plan);
  void Advance(double time);
  void RebuildSegments();
  Eigen::Vector2d ZmpAt(double time, int* segment_hint) const;
  // The front step's swing over [ss_start, end), or false when no foot swings at `time`.
  bool Swinging(double time, int* side, FootSample* sample) const;
  double FrontSingleSupportStart() const { return phase_start_ + queue_[0].double_support; }
  double FrontEnd() const { return FrontSingleSupportStart() + queue_[0].single_support; }

  void CalcFoot(const graph::Tick& t, int side, pinocchio::SE3* out) const;
  void CalcLeftFoot(const graph::Tick& t, pinocchio::SE3* out) const { CalcFoot(t, kLeft, out); }
  void CalcRightFoot(const graph::Tick& t, pinocchio::SE3* out) const { CalcFoot(t, kRight, out); }
  void CalcFootVelocity(const graph::Tick& t, int side, Eigen::VectorXd* out) const;
  void CalcLeftVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
    CalcFootVelocity(t, kLeft, out);
  }
  void CalcRightVelocity(const graph::Tick& t, Eigen::VectorXd* out) const {
    CalcFootVelocity(t, kRight, out);
  }
  void CalcWaist(const graph::Tick& t, pinocchio::SE3* out) const;
  void CalcWaistVelocity(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcZmpWindow(const graph::Tick& t, Eigen::MatrixXd* out) const;
  void CalcZmpReference(const graph::Tick& t, Eigen::VectorXd* out) const;
  void CalcPhase(const graph::Tick& t, int* out) const;
  void CalcPhaseProgress(const graph::Tick& t, double* out) const;
  void CalcStepIndex(const graph::Tick& t, int* out) const;
  void CalcSupport(const graph::Tick& t, int* out) const;
  void CalcPlanId(const graph::Tick& t, int* out) const;

  FootstepManagerOptions options_;
  runtime::SpscQueue<FootstepPlan> mailbox_;
  std::atomic<int64_t> dropped_plans_{0};
  std::array<int64_t, 8> drained_hashes_{};
  int drained_count_ = 0;

  // The walk, written only by Poll and Reset (loop thread).
  Mode mode_ = Mode::kStanding;
  std::array<Footstep, FootstepPlan::kMaxSteps> queue_{};
  int queue_size_ = 0;
  std::array<FootPlacement, 2> feet_;  // planted sole placements (left, right)
  double phase_start_ = 0.0;           // walking: the front step's double-support start;
                                       // stopping: the final double-support start
  Eigen::Vector2d previous_zmp_ = Eigen::Vector2d::Zero();  // ZMP where the current phase started
  Eigen::Vector2d rest_zmp_ = Eigen::Vector2d::Zero();
  bool stopped_ = false;  // StopAfterCurrentStep: no plan taken until Reset
  int64_t current_plan_id_ = 0;
  int64_t applied_plans_ = 0, refused_plans_ = 0, completed_steps_ = 0;
  std::array<ZmpSegment, kMaxSegments> segments_{};
  int num_segments_ = 0;
  Eigen::Vector2d final_zmp_ = Eigen::Vector2d::Zero();  // after the last segment
  // The waist's orientation in the frame of the feet's mean yaw (HoldWaist).
  Eigen::Matrix3d waist_offset_ = Eigen::Matrix3d::Identity();

  graph::OutputSignal<pinocchio::SE3>* left_foot_{};
  graph::OutputSignal<pinocchio::SE3>* right_foot_{};
  graph::OutputSignal<Eigen::VectorXd>* left_velocity_{};
  graph::OutputSignal<Eigen::VectorXd>* right_velocity_{};
  graph::OutputSignal<pinocchio::SE3>* waist_{};
  graph::OutputSignal<Eigen::VectorXd>* waist_velocity_{};
  graph::OutputSignal<Eigen::MatrixXd>* zmp_window_{};
  graph::OutputSignal<Eigen::VectorXd>* zmp_reference_{};
  graph::OutputSignal<int>* phase_{};
  graph::OutputSignal<double>* phase_progress_{};
  graph::OutputSignal<int>* step_index_{};
  graph::OutputSignal<int>* support_{};
  graph::OutputSignal<int>* plan_id_{};
};

}  // namespace marionette::walk
