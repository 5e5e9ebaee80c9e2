// marionette-controller: the 1 kHz controller process (see controller/controller.h).
#include <csignal>
#include <cstdlib>
#include <iostream>

#include "marionette/controller/controller.h"
#include "marionette/controller/robots.h"

namespace {

marionette::controller::Controller* g_controller = nullptr;

void OnSignal(int) {
  if (g_controller != nullptr) g_controller->Stop();
}

constexpr const char* kUsage = R"(usage: marionette-controller [options]

  --robot NAME          talos | tiago | ur10                      (default talos)
  --backend NAME        mujoco | kinematic                        (default mujoco)
  --scene FILE          MJCF scene (mujoco backend; default: the robot alone)
  --lcm-url URL         LCM URL (default $MARIONETTE_LCM_URL, else LCM's default)
  --realtime            ask for SCHED_FIFO and mlockall (says in the log what was refused)
  --duration S          stop after S seconds of controller time (default: until SIGINT)
  --speed X             wall-clock pacing: 1 real time, 2 twice as fast, 0 unpaced (default 1)
  --state-rate HZ       ROBOT_STATE / ROBOT_COMMAND / SIM_OBJECT_POSES rate (default 100)
  --status-rate HZ      CONTROLLER_STATUS rate (default 10)
  --camera-rate HZ      CAMERA_HEAD rate, 0 = off (default 30)
  --camera-size WxH     camera image size (default 640x480)
  --velocity-scale F    fraction of the URDF velocity limits allowed (default 1)
  --timing-log FILE     write every tick's period, compute time and lateness (CSV) at exit
  --no-profiling        do not time every entity (CONTROLLER_TIMING, budgets) each tick
  --overrun-hold-ticks N  hold when an entity overruns its budget N ticks in a row (default 100)
  --models DIR          the models/ folder (default: the repository's)
  --describe-robot      print what the controller knows of --robot as JSON and exit
  -v, --verbose         log every rejected input and controller switch
)";

}  // namespace

int main(int argc, char** argv) {
  namespace mc = marionette::controller;
  mc::ControllerOptions options;
  bool help = false, describe = false;
  try {
    options = mc::ParseOptions(argc, argv, &help, &describe);
  } catch (const std::exception& e) {
    std::cerr << "marionette-controller: " << e.what() << "\n" << kUsage;
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
    } catch (const std::exception& e) {
      std::cerr << "marionette-controller: " << e.what() << "\n";
      return 2;
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
