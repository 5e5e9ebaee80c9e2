// marionette-skeleton-driver: a reference driver of the joint-level protocol (docs/driver.md) for
// a perfect position-servoed robot simulated in software: the measured position is the last
// commanded one, the measured velocity the commanded one. It runs as-is (tests, a dry run of the
// controller); a real robot's driver replaces the three marked places and keeps the rest: the
// absolute-deadline loop, the checks on commands, the watchdog and DRIVER_STATUS. Not written to
// be allocation-free (lcm::LCM::publish encodes into a new buffer, refusals build strings): a
// robot's real-time loop encodes into buffers of its own.
#include <time.h>
#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "marionette/lcm/channels.h"
#include "marionette/lcm/validate.h"
#include "marionette/lcmt_driver_command.hpp"
#include "marionette/lcmt_driver_state.hpp"
#include "marionette/lcmt_driver_status.hpp"

namespace {

constexpr const char* kUsage = R"(usage: marionette-skeleton-driver --joints a,b,c [options]

  --joints A,B,...      the robot's actuated joints (required; docs/driver.md says how to
                        list them, marionette-controller --backend driver logs them)
  --positions X,Y,...   initial positions [rad or m], one per joint (default zeros)
  --wrench-bodies A,..  the bodies whose wrench the robot measures (default none; the
                        controller's --describe-robot: contact_bodies, then grip_bodies)
  --robot NAME          robot_name in DRIVER_STATE and DRIVER_STATUS (default skeleton)
  --lcm-url URL         LCM URL (default $MARIONETTE_LCM_URL, else LCM's default)
  --rate HZ             control rate (default 1000)
  --command-timeout S   watchdog: hold when no command came for S seconds (default 0.01)
  --duration S          stop after S seconds of robot time (default: until SIGINT/SIGTERM)
  --help                this text
)";

volatile std::sig_atomic_t g_stop = 0;

std::vector<std::string> Split(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) out.push_back(item);
  return out;
}

double Number(const std::string& option, const std::string& text) {
  size_t used = 0;
  double value = NAN;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
  }
  if (used != text.size() || !std::isfinite(value))
    throw std::invalid_argument(option + ": not a number: '" + text + "'");
  return value;
}

std::string Milliseconds(double ms) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f ms", ms);
  return text;
}

int64_t Microseconds(const timespec& t) { return int64_t{t.tv_sec} * 1000000 + t.tv_nsec / 1000; }

int64_t MicrosecondsOf(clockid_t clock) {
  timespec t{};
  clock_gettime(clock, &t);
  return Microseconds(t);
}

struct Options {
  std::vector<std::string> joints, wrench_bodies;
  std::vector<double> positions;
  std::string robot = "skeleton", lcm_url;
  double rate = 1000, command_timeout = 0.01, duration = -1;
};

Options Parse(int argc, char** argv) {
  Options o;
  if (const char* url = std::getenv("MARIONETTE_LCM_URL")) o.lcm_url = url;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (a == "--joints") {
      o.joints = Split(value());
    } else if (a == "--positions") {
      o.positions.clear();
      for (const std::string& x : Split(value())) o.positions.push_back(Number(a, x));
    } else if (a == "--wrench-bodies") {
      o.wrench_bodies = Split(value());
    } else if (a == "--robot") {
      o.robot = value();
    } else if (a == "--lcm-url") {
      o.lcm_url = value();
    } else if (a == "--rate") {
      o.rate = Number(a, value());
    } else if (a == "--command-timeout") {
      o.command_timeout = Number(a, value());
    } else if (a == "--duration") {
      o.duration = Number(a, value());
    } else {
      throw std::invalid_argument("unknown option '" + a + "' (--help lists them)");
    }
  }
  std::vector<std::string> sorted = o.joints;
  std::sort(sorted.begin(), sorted.end());
  if (o.joints.empty() || std::count(sorted.begin(), sorted.end(), "") > 0 ||
      std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end())
    throw std::invalid_argument("--joints: a list of distinct, non-empty names is required");
  if (o.positions.empty()) o.positions.assign(o.joints.size(), 0.0);
  if (o.positions.size() != o.joints.size())
    throw std::invalid_argument("--positions: one value per joint");
  if (!(o.rate > 0 && o.rate <= 10000)) throw std::invalid_argument("--rate: in (0, 10000]");
  if (!(o.command_timeout > 0)) throw std::invalid_argument("--command-timeout: > 0");
  return o;
}

class Driver {
 public:
  Driver(const Options& o, lcm::LCM* lcm) : o_(o), lcm_(lcm) {
    const size_t n = o.joints.size();
    state_.protocol_version = 1;
    state_.robot_name = status_.robot_name = o.robot;
    state_.num_joints = static_cast<int32_t>(n);
    state_.joint_name = o.joints;
    state_.joint_position = q_ = hold_q_ = o.positions;
    state_.joint_velocity = v_ = target_v_ = effort_ = std::vector<double>(n, 0.0);
    state_.has_base = false;  // a floating base fills base_* from the robot's estimator
    state_.base_quaternion[0] = 1.0;
    state_.num_wrenches = static_cast<int32_t>(o.wrench_bodies.size());
    state_.wrench_body = o.wrench_bodies;
    state_.wrench.assign(o.wrench_bodies.size(), std::vector<double>(6, 0.0));
    status_.holding = true;
    status_.reason = "no command yet";
    command_.utime = -1;  // none yet: the first state has sequence 1
    lcm_->subscribe(marionette::channels::kDriverCommand, &Driver::OnCommand, this);
  }

  // One control cycle at robot time `now_us`: apply the newest command (or hold), measure, publish.
  void Cycle(int64_t now_us) {
    while (lcm_->handleTimeout(0) > 0) {  // every command received since the last cycle
    }
    // The watchdog first: a command that arrived while this process was stalled is as old as
    // its arrival says, and does not resume tracking.
    const double silent_ms = (now_us - received_us_) / 1e3;
    if (command_.utime >= 0 && silent_ms >= o_.command_timeout * 1e3) {
      if (!status_.holding) Hold(now_us, "no command for " + Milliseconds(silent_ms));
    } else if (fresh_ && command_.mode == 1) {
      Hold(now_us, "hold requested");
    } else if (fresh_) {  // track it (again)
      status_.holding = false;
      status_.reason = "";
      target_q_ = command_.joint_position;
      target_v_ = command_.joint_velocity;
    }
    if (!status_.holding && command_.sequence != state_.sequence) ++status_.commands_late;
    fresh_ = false;
    // SEND TO THE SERVOS HERE: target_q_ (position) and target_v_ (velocity feed-forward), or
    // engage the brakes while holding. The perfect robot reaches its target within the cycle.
    if (status_.holding) {
      q_ = hold_q_;
      std::fill(v_.begin(), v_.end(), 0.0);
    } else {
      q_ = target_q_;
      v_ = target_v_;
    }
    // READ THE ENCODERS HERE (calibrated joint positions), the velocities and the joint torques,
    // and the force/torque sensors into state_.wrench (zeros for a body the robot does not sense).
    state_.joint_position = q_;
    state_.joint_velocity = v_;
    state_.joint_effort = effort_;
    state_.utime = now_us;
    ++state_.sequence;
    lcm_->publish(marionette::channels::kDriverState, &state_);
    if (now_us >= next_status_us_ || status_.holding != published_holding_) PublishStatus(now_us);
  }

  // The robot's clock now: microseconds of CLOCK_MONOTONIC since the driver started.
  // A REAL ROBOT STAMPS ITS OWN CLOCK HERE (the bus's or the servo drives' time).
  int64_t RobotTime() const { return MicrosecondsOf(CLOCK_MONOTONIC) - start_us_; }

 private:
  void OnCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
    // Bounds first (lcmtypes/README.md): LCM's decoder trusts the lengths a message declares.
    const marionette::wire::Verdict verdict =
        marionette::wire::Validate<marionette::lcmt_driver_command>(rbuf->data, rbuf->data_size);
    marionette::lcmt_driver_command c;
    if (!verdict.ok())
      return Refuse(std::string(ToString(verdict.refusal)) + ": " + verdict.detail);
    c.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size));
    std::vector<double> q(o_.joints.size()), v(q.size());
    std::vector<bool> named(q.size(), false);
    for (int i = 0; i < c.num_joints; ++i) {  // joints by name, in any order
      const auto at = std::find(o_.joints.begin(), o_.joints.end(), c.joint_name[i]);
      const size_t j = at - o_.joints.begin();
      if (at == o_.joints.end() || named[j])
        return Refuse("joint '" + c.joint_name[i] + "' unknown or repeated");
      named[j] = true;
      q[j] = c.joint_position[i];
      v[j] = c.joint_velocity[i];
    }
    if (c.num_joints != static_cast<int32_t>(q.size()))
      return Refuse("names " + std::to_string(c.num_joints) + " of the " +
                    std::to_string(q.size()) + " joints");
    if (c.sequence <= command_.sequence || c.utime <= command_.utime)
      return Refuse("out of order: sequence " + std::to_string(c.sequence) + " after " +
                    std::to_string(command_.sequence));
    if (c.sequence > state_.sequence) return Refuse("answers a state not yet published");
    command_ = c;
    command_.joint_position = q;
    command_.joint_velocity = v;
    fresh_ = true;
    // The arrival time on the robot's clock, from the kernel's receive stamp (wall clock).
    const int64_t age_us = MicrosecondsOf(CLOCK_REALTIME) - rbuf->recv_utime;
    received_us_ = RobotTime() - std::max<int64_t>(0, age_us);
    ++status_.commands_taken;
  }

  void Refuse(const std::string& why) {
    ++status_.commands_refused;
    status_.last_refusal = why.substr(0, 1024);
  }

  void Hold(int64_t now_us, const std::string& reason) {
    status_.reason = reason;
    if (status_.holding) return;
    // ENGAGE THE BRAKES HERE, or servo to hold_q_ at zero velocity (below).
    hold_q_ = q_;  // where the robot was measured when the hold began
    status_.holding = true;
    ++status_.holds;
    status_.last_hold_reaction_ms = (now_us - received_us_) / 1e3;
  }

  void PublishStatus(int64_t now_us) {
    status_.utime = now_us;
    status_.sequence = state_.sequence;
    const double wall_s = (MicrosecondsOf(CLOCK_MONOTONIC) - start_us_) / 1e6;
    status_.realtime_factor = wall_s > 0 ? now_us / 1e6 / wall_s : 1.0;
    lcm_->publish(marionette::channels::kDriverStatus, &status_);
    published_holding_ = status_.holding;
    next_status_us_ = now_us + 100000;  // 10 Hz, and at every change of holding
  }

  const Options o_;
  lcm::LCM* lcm_;
  marionette::lcmt_driver_state state_{};
  marionette::lcmt_driver_status status_{};
  marionette::lcmt_driver_command command_{};  // the newest command taken
  std::vector<double> q_, v_, effort_, hold_q_, target_q_, target_v_;
  bool fresh_ = false, published_holding_ = false;
  int64_t received_us_ = 0, next_status_us_ = 0;
  const int64_t start_us_ = MicrosecondsOf(CLOCK_MONOTONIC);
};

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) == "--help" || std::string(argv[i]) == "-h") {
      std::cout << kUsage;
      return 0;
    }
  }
  Options o;
  try {
    o = Parse(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "marionette-skeleton-driver: " << e.what() << "\n";
    return 2;
  }
  lcm::LCM lcm(o.lcm_url);
  if (!lcm.good()) {
    std::cerr << "marionette-skeleton-driver: cannot open LCM '" << o.lcm_url << "'\n";
    return 1;
  }
  std::signal(SIGINT, [](int) { g_stop = 1; });
  std::signal(SIGTERM, [](int) { g_stop = 1; });
  Driver driver(o, &lcm);
  const int64_t period_ns = static_cast<int64_t>(std::llround(1e9 / o.rate));
  timespec deadline{};
  clock_gettime(CLOCK_MONOTONIC, &deadline);
  const auto advance = [&] {
    deadline.tv_nsec += period_ns;
    deadline.tv_sec += deadline.tv_nsec / 1000000000;
    deadline.tv_nsec %= 1000000000;
  };
  int64_t cycles = 0, missed = 0;
  while (!g_stop) {
    const int64_t now_us = driver.RobotTime();
    if (o.duration >= 0 && now_us >= o.duration * 1e6) break;
    driver.Cycle(now_us);
    ++cycles;
    advance();  // the next deadline; those already past are skipped (counted), not run late
    while (Microseconds(deadline) < MicrosecondsOf(CLOCK_MONOTONIC)) advance(), ++missed;
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &deadline, nullptr);
  }
  // A REAL DRIVER ENGAGES THE BRAKES HERE before it exits.
  std::cerr << "marionette-skeleton-driver: " << cycles << " cycles, " << missed
            << " deadlines missed\n";
  return 0;
}
