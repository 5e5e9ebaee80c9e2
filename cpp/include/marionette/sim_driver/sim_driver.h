#pragma once
/// SimDriver: the MuJoCo scene as a robot driver process (marionette-sim; protocol:
/// docs/driver.md, driver_protocol.h). It owns the physics and speaks the protocol a real robot's
/// driver speaks, so that `marionette-controller --backend driver` drives it as it would drive
/// the robot.
///
/// Control cycle k (1 ms of robot time; utime = k * 1000 us from the start):
///   1. the SIM_COMMAND requests received since the last cycle (move a free body, attach or
///      detach a weld), as the controller's mujoco backend applies them;
///   2. mj_step1; DRIVER_STATE k: q and v now, efforts and contact wrenches of the last completed
///      physics step (sim::SceneMeasurement); the scene's range finders now;
///   3. waits for the DRIVER_COMMAND answering k: unpaced (--speed 0) until it comes (lockstep: a
///      split run reproduces the in-process one); paced, until 90 % of the cycle's wall period;
///   4. servo targets from CommandGate (command_gate.h): the answer, else the newest command
///      younger than --command-timeout (a late cycle), else hold where the robot was when the
///      hold began; mj_step2;
///   5. SIM_OBJECT_POSES, RANGE_FINDERS (--state-rate; with utime k's: the readings of state k)
///      and DRIVER_STATUS (10 Hz) from a publisher thread, frames for the camera thread
///      (CAMERA_HEAD, controller::CameraStream).
///
/// Threads: the loop (physics, DRIVER_STATE out and DRIVER_COMMAND in on an LCM instance of its
/// own: no hand-off between receipt and use), the SIM_COMMAND thread (checks signatures with a
/// key, bounds, names; queues requests for the loop), the publisher, the camera (SCHED_IDLE).
/// The loop allocates nothing per cycle after warm-up except on the path of a refused command.

#include <atomic>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace marionette::sim_driver {

struct SimOptions {
  std::string robot;       ///< name on the robot search path, or a folder holding robot.yaml
  std::string scene;       ///< MJCF; default: the robot alone (robot.yaml's mjcf)
  std::string models_dir;  ///< models/ of the repository
  std::string lcm_url;     ///< "" = $MARIONETTE_LCM_URL, else LCM's default
  double speed = 1.0;      ///< 1 real time, 2 twice as fast, 0 lockstep (unpaced)
  double duration = 0.0;   ///< [s] of robot time; 0 = until SIGINT/SIGTERM
  /// Encoder calibration: joint -> offset its encoder reads above the truth.
  std::vector<std::pair<std::string, double>> encoder_offsets;
  double camera_rate = 30.0;  ///< [Hz], 0 = no camera
  int camera_width = 640;
  int camera_height = 480;
  double camera_noise = 0.0;      ///< [grey levels, 1 sigma]
  double depth_noise = 0.0;       ///< [m, 1 sigma]
  double state_rate = 100.0;      ///< [Hz] SIM_OBJECT_POSES
  double command_timeout = 0.01;  ///< [s] the watchdog: hold when no command is younger
  std::string timing_log;         ///< CSV of every cycle's round trip at exit, "" = none
  std::string key_file;           ///< shared key of signed SIM_COMMAND ("" = unsigned)
  bool realtime = false;          ///< ask for SCHED_FIFO and mlockall (as the controller)
  bool verbose = false;
};

/// The command line (`--help` in kSimUsage). Throws std::invalid_argument with one line on a
/// bad argument. $MARIONETTE_LCM_URL and $MARIONETTE_KEY are the defaults of --lcm-url, --key.
SimOptions ParseSimOptions(int argc, char** argv, bool* help);
extern const char kSimUsage[];

class SimDriver {
 public:
  /// Loads the robot and the scene and puts it in its first state (controller::StartScene).
  /// Throws std::runtime_error with one line on a load error (robot, scene, key, LCM URL).
  explicit SimDriver(const SimOptions& options);
  ~SimDriver();
  /// Runs until Stop() or --duration; prints one summary line; returns the exit code.
  int Run();
  /// Ends Run at the next check (async-signal-safe: an atomic store).
  void Stop();

  struct Impl;

 private:
  std::unique_ptr<Impl> impl_;
};

}  // namespace marionette::sim_driver
