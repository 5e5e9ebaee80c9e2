// marionette-sim's command line (sim_driver.h): the controller's flags where they mean the same.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <stdexcept>

#include <tuple>

#include "marionette/controller/command_line.h"
#include "marionette/sim_driver/sim_driver.h"

namespace marionette::sim_driver {

const char kSimUsage[] = R"(usage: marionette-sim --robot NAME|DIR [options]

The MuJoCo scene as a robot driver (docs/driver.md): publishes DRIVER_STATE every 1 ms of robot
time, servos the joints to the DRIVER_COMMAND answering it (marionette-controller --backend
driver), holds when commands stop, and reports on DRIVER_STATUS.

  --robot NAME|DIR      the robot: a name found in --models or $MARIONETTE_ROBOT_PATH, or a
                        folder holding robot.yaml (required; docs/robots.md)
  --scene FILE          MJCF scene (default: the robot alone)
  --models DIR          the models/ folder (robots, scenes; default: the repository's)
  --lcm-url URL         LCM URL (default $MARIONETTE_LCM_URL, else LCM's default)
  --speed X             1 real time, 2 twice as fast, 0 lockstep: each cycle waits for its
                        command (a split run reproduces an in-process one) (default 1)
  --duration S          stop after S seconds of robot time (default: until SIGINT/SIGTERM)
  --realtime            ask for SCHED_FIFO and mlockall (says in the log what was refused)
  --encoder-offsets J=X,...  encoder calibration: joint J's encoder reads X [rad or m] above its
                        true position
  --command-timeout S   the watchdog: run on the newest command while it is younger than S, then
                        hold where the robot is (default 0.01)
  --state-rate HZ       SIM_OBJECT_POSES / RANGE_FINDERS rate (default 100)
  --camera-rate HZ      CAMERA_HEAD rate, 0 = off (default 30)
  --camera-size WxH     camera image size (default 640x480)
  --camera-noise GREY   Gaussian sensor noise on the images [grey levels, 1 sigma] (default 0)
  --depth-noise M       Gaussian noise on the depth pixels with a return [m, 1 sigma] (default 0)
  --timing-log FILE     at exit, one CSV line per cycle: sequence, state -> command round trip
                        [us] (empty: no answer within the cycle), late (1: the cycle ran without
                        its own answer, once commands had begun), holding
  --key FILE            take signed SIM_COMMAND only, with this shared key (default
                        $MARIONETTE_KEY; none: unsigned; lcmtypes/README.md)
  -v, --verbose         log every refused command
)";

SimOptions ParseSimOptions(int argc, char** argv, bool* help) {
  SimOptions o;
  if (const char* url = std::getenv("MARIONETTE_LCM_URL")) o.lcm_url = url;
  if (const char* key = std::getenv("MARIONETTE_KEY")) o.key_file = key;
  *help = false;
  const auto value = [&](int& i) -> std::string {
    if (i + 1 >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs a value");
    return argv[++i];
  };
  const auto number = [&](int& i) -> double {
    const std::string flag = argv[i];
    return controller::ParseNonNegative(flag, value(i));
  };
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "-h" || a == "--help")
      *help = true;
    else if (a == "--robot")
      o.robot = value(i);
    else if (a == "--scene")
      o.scene = value(i);
    else if (a == "--models")
      o.models_dir = value(i);
    else if (a == "--lcm-url")
      o.lcm_url = value(i);
    else if (a == "--speed")
      o.speed = number(i);
    else if (a == "--duration")
      o.duration = number(i);
    else if (a == "--realtime")
      o.realtime = true;
    else if (a == "--encoder-offsets")
      o.encoder_offsets = controller::ParseJointValues(a, value(i));
    else if (a == "--command-timeout")
      o.command_timeout = number(i);
    else if (a == "--state-rate")
      o.state_rate = number(i);
    else if (a == "--camera-rate")
      o.camera_rate = number(i);
    else if (a == "--camera-size")
      std::tie(o.camera_width, o.camera_height) = controller::ParseImageSize(a, value(i));
    else if (a == "--camera-noise")
      o.camera_noise = number(i);
    else if (a == "--depth-noise")
      o.depth_noise = number(i);
    else if (a == "--timing-log")
      o.timing_log = value(i);
    else if (a == "--key")
      o.key_file = value(i);
    else if (a == "-v" || a == "--verbose")
      o.verbose = true;
    else
      throw std::invalid_argument("unknown argument '" + a + "'");
  }
  if (*help) return o;
  if (o.robot.empty())
    throw std::invalid_argument(
        "--robot NAME|DIR is required (`marionette robot list` shows the robots; docs/robots.md)");
  controller::CheckLcmUrl(o.lcm_url);
  if (o.state_rate <= 0.0 || o.state_rate > 1000.0)
    throw std::invalid_argument("--state-rate must be in (0, 1000]");
  if (o.camera_rate > 1000.0) throw std::invalid_argument("--camera-rate must be at most 1000");
  if (o.command_timeout > 10.0)
    throw std::invalid_argument("--command-timeout must be at most 10 s (a watchdog)");
  return o;
}

}  // namespace marionette::sim_driver
