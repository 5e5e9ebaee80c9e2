// marionette-sim: the MuJoCo scene as a robot driver process (see sim_driver/sim_driver.h).
#include <csignal>
#include <cstdlib>
#include <iostream>

#include "marionette/runtime/stop_signals.h"
#include "marionette/sim_driver/sim_driver.h"

namespace {

marionette::sim_driver::SimDriver* g_driver = nullptr;

void OnSignal(int) {
  if (g_driver != nullptr) g_driver->Stop();
}

}  // namespace

int main(int argc, char** argv) {
  marionette::runtime::RestoreStopSignals();  // before any thread: they inherit the mask
  namespace sd = marionette::sim_driver;
  sd::SimOptions options;
  bool help = false;
  try {
    options = sd::ParseSimOptions(argc, argv, &help);
  } catch (const std::exception& e) {
    std::cerr << "marionette-sim: " << e.what() << " (see marionette-sim --help)\n";
    return 2;
  }
  if (help) {
    std::cout << sd::kSimUsage;
    return 0;
  }
  if (options.models_dir.empty()) options.models_dir = MARIONETTE_MODELS_DIR;
  // One llvmpipe thread for the camera: rendering must not take the loop's core.
  setenv("LP_NUM_THREADS", "1", 0);
  setenv("EGL_PLATFORM", "surfaceless", 0);
  try {
    sd::SimDriver driver(options);
    g_driver = &driver;
    std::signal(SIGINT, OnSignal);
    std::signal(SIGTERM, OnSignal);
    const int code = driver.Run();
    g_driver = nullptr;
    return code;
  } catch (const std::exception& e) {
    std::cerr << "marionette-sim: " << e.what() << "\n";
    return 1;
  }
}
