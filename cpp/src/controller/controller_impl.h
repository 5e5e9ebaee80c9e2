#pragma once
// The inside of marionette-controller (controller/controller.h): the Impl shared by
// controller.cc (start-up, the loop), controller_lcm.cc (the LCM thread: inputs, controller
// swaps, introspection) and controller_publish.cc (the publisher thread).

#include <mujoco/mujoco.h>
#include <pthread.h>
#include <sched.h>
#include <Eigen/Geometry>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <mutex>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/parsers/srdf.hpp>
#include <set>
#include <sstream>
#include <thread>
#include "marionette/controller/camera_stream.h"
#include "marionette/controller/controller.h"
#include "marionette/controller/controller_factory.h"
#include "marionette/controller/driver_device.h"
#include "marionette/controller/graph_service.h"
#include "marionette/controller/hold_controller.h"
#include "marionette/controller/measured_base.h"
#include "marionette/controller/reference_stream.h"
#include "marionette/controller/robots.h"
#include "marionette/controller/safety_filter.h"
#include "marionette/controller/sim_start.h"
#include "marionette/graph/arithmetic.h"
#include "marionette/graph/graph.h"
#include "marionette/lcm/channels.h"
#include "marionette/lcm/signing.h"
#include "marionette/lcm/validate.h"
#include "marionette/lcmt_camera_image.hpp"
#include "marionette/lcmt_command.hpp"
#include "marionette/lcmt_controller_journal.hpp"
#include "marionette/lcmt_controller_spec.hpp"
#include "marionette/lcmt_controller_status.hpp"
#include "marionette/lcmt_dg_reply.hpp"
#include "marionette/lcmt_dg_request.hpp"
#include "marionette/lcmt_entity_timings.hpp"
#include "marionette/lcmt_object_poses.hpp"
#include "marionette/lcmt_range_finders.hpp"
#include "marionette/lcmt_robot_command.hpp"
#include "marionette/lcmt_robot_state.hpp"
#include "marionette/lcmt_sim_command.hpp"
#include "marionette/lcmt_supervisor_event.hpp"
#include "marionette/lcmt_task_reference.hpp"
#include "marionette/runtime/log_line.h"
#include "marionette/runtime/loop_clock.h"
#include "marionette/runtime/process_watch.h"
#include "marionette/runtime/spsc_queue.h"
#include "marionette/runtime/timing_stats.h"
#include "marionette/runtime/triple_buffer.h"
#include "marionette/sim/mujoco_device.h"
#include "marionette/sot/kinematic_device.h"
#include "marionette/sot/robot_model.h"

namespace marionette::controller {

using Clock = std::chrono::steady_clock;
inline constexpr double kDt = 1e-3;   // the control period [s]
inline constexpr int kMaxTasks = 64;  // task error norms reported per controller
inline constexpr int kReferenceQueueMessages =
    512;  // TASK_REFERENCE messages LCM may queue
          // (LCM's default, 30, drops a 4 s look-ahead burst)
// COMMAND messages LCM may queue: 10 s of heartbeats. With LCM's default (30: 600 ms of beats),
// an LCM thread kept off the CPU that long lost the beats that came next while the controller's
// own state, queued on its own, went on: it handed over a state newer than the deadline with no
// beat before it, and held a supervisor that had beaten every 20 ms (SupervisorSilence).
inline constexpr int kCommandQueueMessages = 512;
// --realtime: SCHED_FIFO priorities of the loop and of the threads serving it (inputs,
// introspection samples, state): above any normal process, below the loop.
inline constexpr int kLoopPriority = 80;
inline constexpr int kIoPriority = 40;

inline int64_t TickUs(const graph::Tick& t) {
  return static_cast<int64_t>(std::llround(t.time * 1e6));
}

// Why the controller is in its current mode (formatted by the publisher, not the loop).
enum class Reason : int {
  kStartup,  // holding until a controller is accepted
  kControllerAccepted,
  kCommand,           // COMMAND hold / resume / estop / reset_estop
  kWatchdog,          // a streamed reference went stale
  kNonFinite,         // the solver produced NaN/Inf
  kBudget,            // an entity overran its time budget too many ticks in a row
  kSupervisorSilent,  // no heartbeat from the supervisor for --supervisor-timeout
  kDriverSilent,      // no state from the robot's driver for --driver-timeout
  kDriverRefused,     // a state from the robot's driver was refused
};

enum class Command : int { kNone = 0, kHold, kResume, kEstop, kResetEstop, kStop };

// What the loop shares with the publisher each tick (fixed sizes: copied without allocation).
struct Snapshot {
  int64_t tick = 0;
  int64_t utime = 0;
  int mode = static_cast<int>(ControlMode::kHold);
  Reason reason = Reason::kStartup;
  int reason_index = -1;      // stream / task index for the watchdog
  double reason_value = 0.0;  // e.g. the stale age [s]
  int64_t active_id = -1;
  int num_tasks = 0;
  std::array<double, kMaxTasks> task_error{};
  Eigen::VectorXd q, v, q_command, v_command, effort;  // sized at start-up
  Eigen::VectorXd q_kinematics;         // what the features see: measured base, commanded joints
  std::vector<double> wrenches;         // 6 per contact body
  std::vector<double> object_poses;     // 7 per free object (x y z qw qx qy qz)
  std::vector<double> range_distances;  // one per range finder [m] (-1: nothing hit)
  int64_t switches = 0, refused_switches = 0, non_finite_ticks = 0, clamped_ticks = 0;
  int64_t deadline_misses = 0;
  double realtime_factor = 0.0;
  // Walking (active controller with a pattern generator, controller_walk.cc): WALK_STATUS.
  bool walking = false;
  int64_t walk_plan_id = 0;
  int walk_step_index = -1, walk_phase = 0,
      walk_num_queued = 0;  // queued: steps left, in progress included
  double walk_phase_progress = 0.0;
  std::array<double, 3> walk_com{};
  std::array<double, 2> walk_zmp_reference{}, walk_zmp_measured{};
  std::array<double, 4> walk_left{}, walk_right{};
};

// One decision of the loop on a controller posted by the LCM thread.
enum class SwitchState : int { kNone = 0, kPosted, kApplied, kRefused };

// Every entity's window of tick times, copied by the loop once per window (no allocation: the
// table is sized for kMaxEntities at start-up).
inline constexpr int kMaxEntities = 512;
struct TimingTable {
  int64_t graph_version = -1;
  int64_t utime = 0;
  int64_t window_ticks = 0;
  int num_entities = 0;
  std::vector<graph::DurationHistogram> windows;  // kMaxEntities
  std::vector<double> budget_us;
  std::vector<int64_t> overruns;
};

// FNV-1a 64 of a message's bytes: how the journal names the inputs it consumed.
inline int64_t Fnv1a(const void* data, size_t size) {
  uint64_t h = 1469598103934665603ull;
  const auto* p = static_cast<const uint8_t*>(data);
  for (size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 1099511628211ull;
  return static_cast<int64_t>(h);
}

// A consumed input: which channel, which message, at which tick (for deterministic replay).
struct JournalEntry {
  int64_t tick = 0;
  int channel = 0;  // index into kJournalChannels
  int64_t hash = 0;
};
/// Not a channel: the loop's own decision to hold for an overrun budget (timing is not
/// reproducible, so the decision is journaled and replayed as an input).
inline constexpr char kBudgetHoldEntry[] = "CONTROLLER_BUDGET_HOLD";
/// Not a channel: the tick whose configuration a controller spec was built against (its hash;
/// -1: the initial configuration), journaled with the spec's swap — a walking controller's
/// pattern generator takes its CoM height from it, so a replay builds against the same one.
inline constexpr char kBuildTickEntry[] = "CONTROLLER_BUILD_TICK";
/// Not a channel: the loop's decision to hold because the supervisor fell silent (hash 1 when the
/// hold controller was engaged, 0 for a zero-velocity hold), replayed as an input like a budget's.
inline constexpr char kSilenceHoldEntry[] = "CONTROLLER_SILENCE_HOLD";
/// Not a channel: the loop's decision to hold because the robot's driver fell silent (hash 1) or
/// sent a state that was refused (hash 2), taken between two ticks and journaled with the next.
inline constexpr char kDriverHoldEntry[] = "CONTROLLER_DRIVER_HOLD";
inline constexpr const char* kJournalChannels[] = {
    channels::kControllerSpec, channels::kTaskReference, channels::kCommand,
    channels::kSimCommand,     channels::kDgRequest,     kBudgetHoldEntry,
    channels::kFootstepPlan,   kBuildTickEntry,          kSilenceHoldEntry,
    channels::kDriverState,    kDriverHoldEntry};
inline constexpr int kBudgetHoldChannel = 5;
/// A budget-hold entry's hash is the overrunning entity's index, plus this flag when the hold
/// controller was engaged (else the loop held with zero velocity).
inline constexpr int64_t kBudgetHoldEngaged = int64_t{1} << 32;
inline constexpr int kFootstepPlanChannel = 6;  // consumed by the active walking controller's poll
inline constexpr int kBuildTickChannel = 7;
inline constexpr int kSilenceHoldChannel = 8;
inline constexpr int kDriverStateChannel = 9;  // the robot's state of each tick (driver backend)
inline constexpr int kDriverHoldChannel = 10;
/// Driver backend: a robot clock step above this between two states is a jump (refused, hold).
inline constexpr int64_t kMaxDriverClockStepUs = 100000;
/// Ticks the loop retries engaging the hold controller for a silent supervisor while the LCM thread
/// holds the graph lease, before it holds with zero velocity.
inline constexpr int kSilenceEngageRetries = 10;

inline std::string ToLower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

struct Controller::Impl {
  ControllerOptions options;
  RobotInfo robot;
  sot::ModelPtr model;
  std::unique_ptr<sim::MujocoScene> scene;  // mujoco backend
  // Driver backend: the robot's driver on its own LCM instance (states in, commands out), read by
  // the loop thread itself: no hand-off between a state's arrival and its tick.
  std::unique_ptr<lcm::LCM> driver_lcm;
  std::unique_ptr<DriverLayout> driver_layout;
  std::string first_driver_state_bytes;  // the DRIVER_STATE the controller started from
  std::unique_ptr<MeasuredState> first_driver_state_read;  // the same, read once
  int64_t driver_state_hash = 0;  // of the state the next tick reads (the journal's)
  bool driver_silent = false;     // loop: a silence hold was decided, no state since
  Clock::time_point last_driver_state = Clock::now();  // loop: when the last state was taken
  std::unique_ptr<graph::Graph> graph;
  std::unique_ptr<ControllerFactory> factory;
  lcm::LCM lcm;

  // Persistent entities.
  graph::Device* device = nullptr;        // the robot: MuJoCo here, or behind a driver
  DriverDevice* driver_device = nullptr;  // the driver backend's device
  sot::KinematicDevice* command = nullptr;
  MeasuredBase* measured_base = nullptr;
  sot::RobotModel* robot_model = nullptr;
  SafetyFilter* safety = nullptr;
  graph::OutputSignal<Eigen::VectorXd>* q_kinematics = nullptr;  // what features see

  std::vector<std::string> joint_names;  // 1-dof joints, Pinocchio order
  std::vector<int> joint_q, joint_v;     // their indices
  std::vector<sot::FrameRef>
      contact_frames;                     // robot.contact_bodies as Pinocchio frames (walking ZMP)
  std::vector<std::string> free_objects;  // scene bodies with a free joint (not the robot)
  std::vector<int> free_object_ids;
  RangeFinderSet range_finders;  // the scene's rangefinder sensors (sim_start.h)

  // Loop-owned.
  std::atomic<bool> stop{false};
  std::mt19937_64 range_noise{0};  // the range finders' noise (seeded: a run reads it again)
  BuiltController* active = nullptr;
  std::vector<ReferenceStream*> active_streams;  // reserved: no allocation when swapping
  ControlMode mode = ControlMode::kHold;
  Snapshot loop_state;  // written by the loop, copied to the buffer

  // Loop <-> LCM thread.
  std::atomic<int> switch_state{static_cast<int>(SwitchState::kNone)};
  BuiltController* posted = nullptr;  // valid while switch_state == kPosted
  double refused_jump = 0.0;          // written before kRefused
  int refused_jump_v = -1;            // the velocity index that jumped most (with it)
  int64_t decided_tick = -1;          // written before kApplied / kRefused
  std::atomic<int> command_request{static_cast<int>(Command::kNone)};
  std::atomic<int64_t> command_hash{0};  // of the message behind command_request
  int64_t posted_hash = 0;               // of the spec behind `posted`
  int64_t posted_build_tick = -1;        // the tick of the configuration it was built against
  runtime::SpscQueue<SimRequest> sim_requests{64};  // sim_start.h; hash: for the journal

  // Loop -> publisher / camera.
  std::unique_ptr<runtime::TripleBuffer<Snapshot>> snapshots;
  runtime::SpscQueue<runtime::TickTiming> timings{20000};
  std::unique_ptr<CameraStream> camera;  // the head camera (mujoco backend)

  // The boundary (LCM thread): signed commands when a key is given (nullptr: unsigned).
  std::unique_ptr<wire::Verifier> verifier;

  // The supervisor's heartbeat (LCM thread): any accepted spec, reference chunk or command
  // (COMMAND "heartbeat" among them) is one. While a supervisor's controller is active, a silence
  // of --supervisor-timeout raises silence_request; the loop then holds (HoldOnSilence). Times are
  // when the kernel received the messages (LCM's recv_utime, wall clock [us]): LCM's reader thread
  // queues what arrives while this thread builds a controller, and hands it over in arrival order,
  // so the silence is measured up to the arrival of the newest message handed over, the
  // controller's own ROBOT_STATE heard back among them (SupervisorSilence) — neither a long build,
  // nor a flood of other messages, nor a reader thread kept off the CPU changes it.
  int64_t last_heartbeat_us = 0;
  int64_t newest_arrival_us = 0;  // of the newest message handed over, any channel
  std::string driver;             // the source of the last COMMAND heard
  bool silence_raised = false;    // once per silence: the next heartbeat clears it
  // The process of the last heartbeat that named itself (same machine): its exit raises the
  // silence at once instead of after the timeout. The LCM thread's wait polls its pidfd.
  runtime::ProcessWatch supervisor_process;
  bool process_watch_noted = false;  // why a sender cannot be watched, logged once
  std::atomic<bool> silence_request{false};
  std::atomic<double> silence_seconds{0.0};  // how long it had been silent, for the status
  int silence_retries = 0;                   // loop: ticks waiting for the graph lease
  int64_t replay_silence_hold = -1;          // replay: 1 engage the hold controller, 0 hold
  // Driver backend (loop thread): a hold decided between ticks (1 silent, 2 refused state), applied
  // and journaled at the start of the next tick; the refusals, for the LCM thread to count.
  int64_t driver_hold = 0;
  struct DriverRefusalEvent {
    std::string category, detail;
  };
  runtime::SpscQueue<DriverRefusalEvent> driver_refusals{64};
  std::atomic<int64_t> driver_refusals_lost{0};
  std::string silence_driver;       // under stats_mutex: who fell silent
  int silence_exited_pid = 0;       // under stats_mutex: the silence is this process's exit
  std::string last_driver_refusal;  // under stats_mutex: the last refused DRIVER_STATE

  // LCM-thread-owned.
  std::map<int64_t, std::unique_ptr<BuiltController>> controllers;  // posted or active
  int64_t active_owned_id = -1;
  std::deque<std::pair<lcmt_controller_spec, int64_t>> waiting_specs;  // with the message's hash

  // Introspection (DG_REQUEST) and timing.
  GraphService service;
  struct PendingGet {
    int64_t request_id;
    std::string client;
    std::vector<std::string> names;
  };
  std::deque<lcmt_dg_request> waiting_dg;  // served when no swap is pending
  std::deque<int64_t> dg_hashes;           // the hash of each waiting request
  int64_t current_dg_hash = 0;
  lcmt_entity_timings last_timing{};  // the last CONTROLLER_TIMING published
  std::vector<PendingGet> gets;
  struct Trace {
    int64_t request_id = -1;
    std::string client;
    std::vector<std::string> names;
    int64_t period_ticks = 1;
    int64_t next_tick = 0;
  } trace;
  int64_t watch_id = -1;
  std::vector<std::string> watch_names;  // the current watch's signals, in order
  std::unique_ptr<runtime::TripleBuffer<TimingTable>> timing_tables;  // loop -> LCM thread
  int64_t timing_window_ticks = 1000;
  std::vector<const graph::Entity*> overran;  // loop scratch (reserved)
  int64_t overrun_hold_ticks = 100;           // consecutive overruns before holding
  runtime::SpscQueue<std::pair<int64_t, int>> overrun_events{256};  // (tick, entity index)

  // The hold controller (hold_controller.h): built and armed by the LCM thread against the
  // running controller, engaged by the loop on repeated overruns, collected by the LCM thread.
  enum HoldState : int { kHoldEmpty = 0, kHoldArmed, kHoldEngaged, kHoldStale };
  std::atomic<int> hold_state{kHoldEmpty};
  std::unique_ptr<BuiltController> hold_controller;  // LCM-thread-owned, lent while armed
  BuiltController* armed_hold = nullptr;             // for the loop, valid while kHoldArmed
  int64_t hold_engaged_tick = -1;                    // written by the loop before kHoldEngaged
  Reason hold_engaged_why = Reason::kBudget;         // likewise
  int64_t hold_unbuildable_for = -1;                 // active id whose hold failed to build
  int64_t last_decision_utime = 0;                   // of the last swap (LcmThread arms 1 s later)
  std::vector<std::string> soles;                    // robot.contact_bodies the model has
  // The graph's structure is read off the loop only under this lease (0 free, 1 LCM thread,
  // 2 loop); the loop engages the hold controller only if it gets the lease at once.
  std::atomic<int> graph_lease{0};
  enum class Engage { kEngaged, kRetry, kUnavailable };

  // The black box (--journal FILE): a local LCM log of every input the LCM thread admits, every
  // journal batch and (driver backend) every robot state the loop takes, so that a replay never
  // depends on a network logger, which drops messages when its process falls behind (a plank
  // flip's lcm-logger lost 5 of 1042 consumed inputs at load 3.5).
  std::unique_ptr<lcm::LogFile> black_box;
  std::mutex black_box_mutex;
  int64_t black_box_events = 0;  // under black_box_mutex
  void Record(const std::string& channel, const void* data, size_t size, int64_t utime);
  // Driver states, loop -> publisher (written to the black box off the loop, drained at every
  // wake of the publisher: 100 Hz covers an unpaced loop's 10 kHz). Slots hold twice the first
  // state's size (allocated at start-up); a larger state is counted lost.
  static constexpr size_t kStateRecords = 1024;
  std::unique_ptr<runtime::SpscQueue<std::vector<uint8_t>>> state_records;
  std::vector<uint8_t> state_record_scratch;
  std::atomic<int64_t> records_lost{0};
  void RecordDriverStates();  // publisher thread

  // Journal of consumed inputs (loop -> publisher) for deterministic replay.
  runtime::SpscQueue<JournalEntry> journal{1 << 14};
  std::atomic<int64_t> journal_lost{0};
  bool replaying = false;           // offline replay: budgets come from the journal
  int64_t replay_budget_hold = -1;  // replay: entity index to hold for at this tick

  // Shared between non-real-time threads.
  std::mutex shared_mutex;   // the publisher's latest snapshot, for the LCM thread
  Eigen::VectorXd shared_q;  // kinematics configuration (nq): measured base, commanded joints
  int64_t shared_utime = 0;
  int64_t shared_tick = -1;  // the tick of shared_q (-1: the initial configuration)
  std::mutex stats_mutex;
  std::map<std::string, int64_t> rejections;  // "CHANNEL: category" -> count
  int64_t num_rejected = 0;
  std::string last_rejection;
  // The decision text is published with the first snapshot of the tick that took it, never
  // before: a status never says "accepted" while still showing the previous active id.
  std::string last_switch_result;
  std::string pending_switch_result;
  int64_t pending_switch_tick = -1;
  struct Names {
    std::string controller;
    std::vector<std::string> tasks;    // in the order of BuiltController::task_errors
    std::vector<std::string> streams;  // in the order of the loop's active_streams
  };
  std::map<int64_t, Names> names_by_id;

  /// `first_driver_state` (driver backend): the bytes of the robot's first DRIVER_STATE, as a
  /// replay knows them; live (nullptr), the controller waits for it.
  explicit Impl(const ControllerOptions& o, const std::string* first_driver_state = nullptr);
  void BuildPersistentGraph(const Eigen::VectorXd& q0);
  void Reject(const std::string& channel, const std::string& category, const std::string& detail);

  // Loop.
  void LoopTick(const graph::Tick& t, runtime::LoopClock& clock);
  void ApplyCommand(const graph::Tick& t);
  void CheckBudgets(const graph::Tick& t);
  void CopyTimings(const graph::Tick& t);
  void DecideSwitch(const graph::Tick& t);
  void Watchdog(const graph::Tick& t);
  void HoldOnSilence(const graph::Tick& t);
  /// Driver backend, between ticks: waits up to `timeout_s` of wall time for the next state the
  /// device takes (true), else decides a silence hold (false). Offers each message on the way.
  bool WaitDriverState(double timeout_s);
  /// A DRIVER_STATE (loop thread, from WaitDriverState; or the replay): offered to the device; a
  /// refused one is counted and holds the robot.
  void OnDriverState(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  /// The driver hold decided between ticks, in the status at once (`seconds`: of silence).
  void ShowDriverHold(double seconds);
  /// Holds for the driver (driver_hold: 1 silent, 2 refused state) and journals it at tick t.
  void ApplyDriverHold(const graph::Tick& t);
  /// `why`: kBudget or kSupervisorSilent (said by the LCM thread when it collects the swap).
  Engage EngageHoldController(const graph::Tick& t, Reason why);
  void FillSnapshot(const graph::Tick& t, const runtime::LoopClock& clock);
  void FillWalkStatus(const graph::Tick& t, Snapshot* s);  // controller_walk.cc

  // LCM thread.
  void LcmThread();
  /// Every input message passes here before its handler: the signature (with a key), the
  /// schema's bounds and ranges (@clock against the controller's time), then lcm-gen's decode.
  /// False when it is refused (counted under the channel and the reason).
  template <typename Msg>
  bool Admit(const char* channel, const lcm::ReceiveBuffer* rbuf, Msg* msg);
  /// Runs `handle` so that no exception leaves an LCM handler: one is counted as "internal error".
  template <typename Handle>
  void Guarded(const char* channel, Handle&& handle);
  void Heard(const std::string& source, int64_t arrival_us);  // a heartbeat
  /// The controller's own ROBOT_STATE, heard back: the receive path flows up to its arrival.
  void OnOwnState(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void WatchSupervisor(bool idle);  // after each wait: raises silence_request
  /// Waits up to WaitMs() for a message or the watched supervisor's exit; true: a message waits
  /// (the caller handles it, after collecting what the loop decided meanwhile).
  bool WaitForMessage();
  /// From a heartbeat that names its process: watch that process's exit.
  void WatchSupervisorProcess(const lcmt_command& heartbeat);
  /// The watched supervisor process `pid` exited: RaiseSilence when its controller runs.
  void SupervisorExited(int pid);
  /// Asks the loop to hold: silent for `silent_s`, or (exited_pid > 0) that process exited.
  void RaiseSilence(double silent_s, int exited_pid);
  void CountDriverRefusals();  // the loop's refused DRIVER_STATEs, counted here
  int WaitMs();                // how long the next wait may be (the silence's deadline)
  void OnSpec(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void OnReference(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void OnCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void OnSimCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void ReceiveReference(const lcm::ReceiveBuffer* rbuf);  // the handlers' bodies, guarded
  void ReceiveCommand(const lcm::ReceiveBuffer* rbuf);
  void ReceiveSimCommand(const lcm::ReceiveBuffer* rbuf);
  void ReceiveFootstepPlan(const lcm::ReceiveBuffer* rbuf);  // controller_walk.cc
  void OnFootstepPlan(const lcm::ReceiveBuffer* rbuf,
                      const std::string& channel);  // controller_walk.cc
  void PostNextSpec();
  void ArmHoldController();
  void CollectHoldController();
  void CollectSwitchDecision();
  // " (<joint>)": the joint whose command jumped most at the last refused switch, or "".
  std::string JumpedJoint() const;
  void OnDgRequest(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void ServeDg();
  void ServeDgRequest(const lcmt_dg_request& request);
  void ServeSamples();
  void UpdateWatch();
  void ReplyDg(const lcmt_dg_request& request, bool ok, const std::string& error,
               const std::string& text = "");
  void PublishTiming();
  std::string TimingText();
  int64_t loop_utime() {
    std::lock_guard<std::mutex> lock(shared_mutex);
    return shared_utime;
  }
  void Journal(int64_t tick, int channel, int64_t hash);
  /// The options that decide the motion, as a command line (journaled for replay).
  std::string MotionConfig() const;
  void PublishJournal(int64_t utime, bool always);

  // Publisher and camera threads.
  void PublisherThread();
  void PublishState(const Snapshot& s);
  void PublishWalkStatus(const Snapshot& s);  // controller_walk.cc
  void PublishStatus(const Snapshot& s, runtime::TimingWindow& period,
                     runtime::TimingWindow& compute, runtime::TimingWindow& lateness);
};

inline int64_t WallUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

template <typename Msg>
bool Controller::Impl::Admit(const char* channel, const lcm::ReceiveBuffer* rbuf, Msg* msg) {
  newest_arrival_us = std::max(newest_arrival_us, rbuf->recv_utime);
  const void* data = rbuf->data;
  size_t size = rbuf->data_size;
  // A replay takes the messages the live run took: their signatures were checked then.
  if (verifier && !replaying) {
    std::string detail;
    const wire::SignatureCheck check =
        verifier->Verify(channel, data, size, WallUs(), &size, &detail);
    if (check != wire::SignatureCheck::kAccepted) {
      Reject(channel, wire::ToString(check), detail);
      return false;
    }
  }
  const int64_t now_us = loop_utime();
  wire::Verdict verdict = wire::Validate<Msg>(data, size, now_us);
  if (verdict.refusal == wire::Refusal::kTrailingBytes && wire::HasTrailer(data, size) &&
      (verifier == nullptr || replaying)) {
    if (!replaying) {
      Reject(channel, "signed, no key",
             "a signed message, and this controller has no key to check it (--key FILE or "
             "MARIONETTE_KEY)");
      return false;
    }
    size -= wire::kTrailerSize;
    verdict = wire::Validate<Msg>(data, size, now_us);
  }
  if (!verdict.ok()) {
    Reject(channel, wire::ToString(verdict.refusal), verdict.detail);
    return false;
  }
  // Bounds checked: lcm-gen's decoder reads within the buffer and allocates what was declared.
  if (msg->decode(data, 0, static_cast<int>(size)) != static_cast<int>(size)) {
    Reject(channel, "undecodable", std::string("not a valid ") + Msg::getTypeName());
    return false;
  }
  if (black_box && !replaying) Record(channel, rbuf->data, rbuf->data_size, rbuf->recv_utime);
  return true;
}

template <typename Handle>
void Controller::Impl::Guarded(const char* channel, Handle&& handle) {
  const auto count = [&](const char* what) {
    try {
      Reject(channel, "internal error", what);
    } catch (...) {  // out of memory: nothing more to do than not to throw
    }
  };
  try {
    handle();
  } catch (const std::exception& e) {
    count(e.what());
  } catch (...) {
    count("unknown exception");
  }
}

}  // namespace marionette::controller
