#pragma once
/// Controller: the marionette-controller process. It owns the robot (MuJoCo scene or kinematic
/// integrator), the persistent part of the graph, the 1 kHz loop and the threads around it:
///
///   loop thread      Read → Evaluate → (swap a new controller at the tick boundary) → Write,
///                    on absolute deadlines; never allocates, locks or does I/O after warm-up
///   LCM thread       decodes and validates every input message, builds new controllers
///                    (ControllerFactory) and pushes streamed references into their streams
///   publisher thread ROBOT_STATE, ROBOT_COMMAND (configurable rate), CONTROLLER_STATUS (10 Hz),
///                    SIM_OBJECT_POSES (simulator ground truth), RANGE_FINDERS (the MuJoCo
///                    scene's rangefinder sensors, when it has some), from lock-free snapshots
///   camera thread    renders the head RGB-D camera from a state snapshot (CAMERA_HEAD)
///
/// Persistent graph: device (MuJoCo, or a robot's driver) → measured_base → robot (RobotModel) →
/// [controller] → safety (SafetyFilter) → command (KinematicDevice: the integrated position
/// command) → device. With the kinematic backend the command integrator is the robot.
///
/// Modes: hold (zero velocity, the servos hold the last command) until a controller is
/// accepted; run; hold again when a streamed reference goes stale (watchdog) or on COMMAND
/// "hold"; estop latches until "reset_estop". An entity over its time budget for
/// --overrun-hold-ticks ticks in a row engages the hold controller (hold_controller.h: balance
/// + posture for humanoids, posture for arms; status "holding", active id -2), or holds with
/// zero velocity when it is not armed. So does a supervisor that falls silent: while a
/// supervisor's controller runs, no heartbeat (COMMAND "heartbeat", or any accepted spec,
/// reference chunk or command) for --supervisor-timeout holds the robot (status "holding",
/// "supervisor silent"); a new spec resumes. Every input message is checked against its type's
/// declared bounds before it is decoded (lcm/validate.h) and, with a key, its signature
/// (lcm/signing.h); every rejected input is counted with its reason in CONTROLLER_STATUS; no
/// exception leaves an LCM handler; the robot never moves on garbage.

#include <atomic>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace marionette::controller {

struct ControllerOptions {
  std::string robot;  ///< name on the robot search path, or a folder holding robot.yaml
  std::string backend = "mujoco";  ///< "mujoco" | "kinematic" | "driver" (docs/driver.md)
  std::string scene;               ///< MJCF (mujoco backend); default: the robot alone
  /// Encoder calibration (mujoco backend): joint -> offset its encoder reads above the truth.
  std::vector<std::pair<std::string, double>> encoder_offsets;
  std::string models_dir;     ///< models/ of the repository
  std::string lcm_url;        ///< "" = $MARIONETTE_LCM_URL, else LCM's default
  bool realtime = false;      ///< ask for SCHED_FIFO + mlockall
  double duration = 0.0;      ///< [s] of controller time; 0 = until SIGINT/SIGTERM
  double speed = 1.0;         ///< wall-clock pacing: 1 = real time, 0 = as fast as possible
  double state_rate = 100.0;  ///< [Hz] ROBOT_STATE / ROBOT_COMMAND / SIM_OBJECT_POSES
  double status_rate = 10.0;  ///< [Hz] CONTROLLER_STATUS
  double camera_rate = 30.0;  ///< [Hz], 0 = no camera
  int camera_width = 640;
  int camera_height = 480;
  double camera_noise =
      0.0;  ///< [grey levels] sensor noise on every camera frame (sim::CameraNoise)
  double depth_noise = 0.0;          ///< [m] on every camera depth pixel that has a return
  double velocity_scale = 1.0;       ///< fraction of the URDF velocity limits the safety allows
  std::string timing_log;            ///< write every tick's timing here (CSV) at exit, "" = no
  bool profiling = true;             ///< per-entity compute time (CONTROLLER_TIMING, budgets)
  int64_t overrun_hold_ticks = 100;  ///< hold after this many consecutive over-budget ticks
  /// [s] hold when the supervisor of the active controller is silent this long (no heartbeat,
  /// spec, reference chunk or command); 0 = never
  double supervisor_timeout = 0.1;
  /// The shared key of signed commands ("" = $MARIONETTE_KEY, none: unsigned commands)
  std::string key_file;
  /// An LCM log the controller writes itself: every input it admits and its journal (the
  /// robot's states too with a driver), what `--replay` needs even when a network logger dropped
  /// messages ("" = none)
  std::string journal_file;
  /// [s] driver backend: hold when no DRIVER_STATE came for this long (wall clock)
  double driver_timeout = 0.01;
  bool verbose = false;
};

class Controller {
 public:
  /// Loads the robot and the scene, builds the persistent graph and opens LCM; throws
  /// std::runtime_error with a precise message on any problem (missing file, bad robot...).
  explicit Controller(const ControllerOptions& options);
  ~Controller();
  Controller(const Controller&) = delete;
  Controller& operator=(const Controller&) = delete;

  /// Runs until the duration elapses or Stop() is called; returns the process exit code.
  int Run();
  /// Thread- and signal-safe.
  void Stop();

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

/// Parses the command line (see --help); throws std::invalid_argument on bad arguments.
ControllerOptions ParseOptions(int argc, char** argv, bool* help, bool* describe_robot);

}  // namespace marionette::controller
