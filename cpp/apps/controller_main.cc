// marionette-controller: the 1 kHz controller process (see controller/controller.h).
#include <csignal>
#include <cstdlib>
#include <iostream>

#include <cstring>
#include <fstream>
#include <string>

#include "marionette/controller/controller.h"
#include "marionette/controller/replay.h"
#include "marionette/controller/robots.h"
#include "marionette/runtime/stop_signals.h"

namespace {

marionette::controller::Controller* g_controller = nullptr;

void OnSignal(int) {
  if (g_controller != nullptr) g_controller->Stop();
}

constexpr const char* kUsage = R"(usage: marionette-controller [options]

  --robot NAME|DIR      the robot: a name found in --models or $MARIONETTE_ROBOT_PATH, or a
                        folder holding robot.yaml (required; docs/robots.md)
  --backend NAME        mujoco: MuJoCo in this process; kinematic: perfect velocity integration;
                        driver: the robot behind a driver process (a real robot's, or
                        marionette-sim) on DRIVER_STATE / DRIVER_COMMAND, one tick per state
                        (docs/driver.md)                            (default mujoco)
  --scene FILE          MJCF scene (mujoco backend; default: the robot alone)
  --driver-timeout S    driver backend: hold when no DRIVER_STATE came for S seconds (default 0.01)
  --encoder-offsets J=X,...  encoder calibration (mujoco backend): joint J's encoder reads X
                        [rad or m] above its true position (e.g. from marionette calibrate)
  --lcm-url URL         LCM URL (default $MARIONETTE_LCM_URL, else LCM's default)
  --realtime            ask for SCHED_FIFO and mlockall (says in the log what was refused)
  --duration S          stop after S seconds of controller time (default: until SIGINT)
  --speed X             wall-clock pacing: 1 real time, 2 twice as fast, 0 unpaced (default 1)
  --state-rate HZ       ROBOT_STATE / ROBOT_COMMAND / SIM_OBJECT_POSES / RANGE_FINDERS rate
                        (default 100)
  --status-rate HZ      CONTROLLER_STATUS rate (default 10)
  --camera-rate HZ      CAMERA_HEAD rate, 0 = off (default 30)
  --camera-size WxH     camera image size (default 640x480)
  --camera-noise GREY   Gaussian sensor noise on the images [grey levels, 1 sigma] (default 0)
  --depth-noise M       Gaussian noise on the depth pixels with a return [m, 1 sigma] (default 0)
  --velocity-scale F    fraction of the URDF velocity limits allowed (default 1)
  --timing-log FILE     write every tick's period, compute time and lateness (CSV) at exit
  --journal FILE        write every input taken and the journal to this LCM log (what --replay
                        needs, even when a network logger dropped messages)
  --no-profiling        do not time every entity (CONTROLLER_TIMING, budgets) each tick
  --overrun-hold-ticks N  hold when an entity overruns its budget N ticks in a row (default 100)
  --supervisor-timeout S  hold when the supervisor of the running controller is silent S seconds
                        (no heartbeat, spec, reference or command; default 0.1, 0 = never),
                        and at once when its process exits (a heartbeat from this machine)
  --key FILE            take signed commands only, with this shared key (default $MARIONETTE_KEY;
                        none: unsigned commands; lcmtypes/README.md)
  --models DIR          the models/ folder (robots, scenes; default: the repository's)
  --describe-robot      print what the controller knows of --robot as JSON and exit
  -v, --verbose         log every rejected input and controller switch

usage: marionette-controller --replay LOG [--journal FILE] [--scene FILE] [--tolerance X]
                             [--max-ticks N] [--json FILE] [--models DIR]

  Re-runs a recorded run offline on a simulated clock from the inputs its journal says the loop
  consumed (CONTROLLER_JOURNAL in the LCM log, or in the controller's own --journal FILE), and
  compares every recorded ROBOT_COMMAND of LOG.
  Exit code 0 when every command matches within --tolerance (default 1e-9); --max-ticks N
  replays the first N ticks only.
)";

// marionette-controller --replay LOG ...: see kUsage.
int Replay(int argc, char** argv) {
  namespace mc = marionette::controller;
  mc::ReplayOptions o;
  o.models_dir = MARIONETTE_MODELS_DIR;
  std::string json;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (a == "--replay")
      o.log = value();
    else if (a == "--scene")
      o.scene = value();
    else if (a == "--journal")
      o.journal = value();
    else if (a == "--models")
      o.models_dir = value();
    else if (a == "--json")
      json = value();
    else if (a == "--tolerance")
      o.tolerance = std::stod(value());
    else if (a == "--max-ticks")
      o.max_ticks = std::stoll(value());
    else if (a == "-v" || a == "--verbose")
      o.verbose = true;
    else
      throw std::invalid_argument("unknown replay argument '" + a + "' (see --help)");
  }
  const mc::ReplayResult r = mc::ReplayLog(o);
  std::cout << "replayed " << r.ticks << " ticks of '" << r.config << "': " << r.inputs
            << " inputs, " << r.commands_compared << " recorded commands compared, max difference "
            << r.max_difference << "\n";
  if (r.first_divergence_tick >= 0) {
    std::cout << "first divergence at tick " << r.first_divergence_tick << ": "
              << r.first_divergence << "\n";
  }
  if (r.journal_mismatches > 0) {
    std::cout << r.journal_mismatches
              << " ticks consumed other inputs than recorded; first: " << r.first_journal_mismatch
              << "\n";
  }
  for (const std::string& p : r.problems) std::cout << "problem: " << p << "\n";
  if (r.commands_compared == 0) std::cout << "problem: the log holds no ROBOT_COMMAND to compare\n";
  std::cout << (r.ok() ? "replay matches the recording" : "replay does NOT match the recording")
            << "\n";
  if (!json.empty()) std::ofstream(json) << r.ToJson() << "\n";
  return r.ok() ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  marionette::runtime::RestoreStopSignals();  // before any thread: they inherit the mask
  namespace mc = marionette::controller;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--replay") == 0) {
      try {
        return Replay(argc, argv);
      } catch (const std::invalid_argument& e) {  // the command line (docs/errors.md: usage)
        std::cerr << "marionette-controller --replay: " << e.what() << "\n";
        return 2;
      } catch (const std::exception& e) {  // the log: missing, unreadable
        std::cerr << "marionette-controller --replay: " << e.what() << "\n";
        return 1;
      }
    }
  }
  mc::ControllerOptions options;
  bool help = false, describe = false;
  try {
    options = mc::ParseOptions(argc, argv, &help, &describe);
  } catch (const std::exception& e) {
    std::cerr << "marionette-controller: " << e.what() << " (see marionette-controller --help)\n";
    return 2;
  }
  if (help) {
    std::cout << kUsage;
    return 0;
  }
  if (options.models_dir.empty()) options.models_dir = MARIONETTE_MODELS_DIR;
  if (describe) {
    try {
      std::cout << mc::ToJson(mc::FindRobot(options.robot, options.models_dir)) << "\n";
      return 0;
    } catch (const std::exception& e) {  // an unknown robot, an invalid robot.yaml
      std::cerr << "marionette-controller: " << e.what() << "\n";
      return 1;
    }
  }
  // One llvmpipe thread for the camera: rendering must not take the loop's core.
  setenv("LP_NUM_THREADS", "1", 0);
  setenv("EGL_PLATFORM", "surfaceless", 0);
  try {
    mc::Controller controller(options);
    g_controller = &controller;
    std::signal(SIGINT, OnSignal);
    std::signal(SIGTERM, OnSignal);
    const int code = controller.Run();
    g_controller = nullptr;
    return code;
  } catch (const std::exception& e) {
    std::cerr << "marionette-controller: " << e.what() << "\n";
    return 1;
  }
}
