// driver_echo: the trivial end of the driver protocol, to measure a driver's round trip
// (tests/python/sim_driver): answers every DRIVER_STATE at once with a DRIVER_COMMAND echoing its
// sequence and utime that holds the first state's joint positions. No validation, no model: the
// least a controller can do per state.
//
//   driver_echo LCM_URL [SECONDS]     (default: until SIGINT/SIGTERM)
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <lcm/lcm-cpp.hpp>
#include <vector>

#include "marionette/lcm/channels.h"
#include "marionette/lcmt_driver_command.hpp"
#include "marionette/lcmt_driver_state.hpp"

namespace {

volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

struct Echo {
  lcm::LCM* lcm;
  marionette::lcmt_driver_state state;
  marionette::lcmt_driver_command command{};
  std::vector<uint8_t> buffer;
  bool started = false;
  long answered = 0;

  void Handle(const lcm::ReceiveBuffer* rbuf, const std::string&) {
    const int size = static_cast<int>(rbuf->data_size);
    if (state.decode(rbuf->data, 0, size) != size) return;
    if (!started) {
      command.protocol_version = 1;
      command.mode = 0;
      command.num_joints = state.num_joints;
      command.joint_name = state.joint_name;
      command.joint_position = state.joint_position;
      command.joint_velocity.assign(state.num_joints, 0.0);
      command.joint_effort.assign(state.num_joints, 0.0);
      buffer.resize(command.getEncodedSize());
      started = true;
    }
    command.utime = state.utime;
    command.sequence = state.sequence;
    const int n = command.encode(buffer.data(), 0, static_cast<int>(buffer.size()));
    lcm->publish(marionette::channels::kDriverCommand, buffer.data(), n);
    ++answered;
  }
};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: driver_echo LCM_URL [SECONDS]\n");
    return 2;
  }
  lcm::LCM lcm(argv[1]);
  if (!lcm.good()) return 1;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  Echo echo{&lcm, {}, {}, {}, false, 0};
  lcm.subscribe(marionette::channels::kDriverState, &Echo::Handle, &echo);
  const double seconds = argc > 2 ? std::atof(argv[2]) : 0.0;
  const auto end = std::chrono::steady_clock::now() +
                   std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                       std::chrono::duration<double>(seconds));
  while (!g_stop && (seconds <= 0.0 || std::chrono::steady_clock::now() < end))
    lcm.handleTimeout(10);
  std::printf("driver_echo: answered %ld states\n", echo.answered);
  return 0;
}
