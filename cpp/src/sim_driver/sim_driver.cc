// marionette-sim: the MuJoCo scene as a robot driver (sim_driver.h).
#include "marionette/sim_driver/sim_driver.h"

#include <poll.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <lcm/lcm-cpp.hpp>
#include <mutex>
#include <thread>

#include "marionette/controller/camera_stream.h"
#include "marionette/controller/driver_protocol.h"
#include "marionette/controller/robots.h"
#include "marionette/controller/sim_start.h"
#include "marionette/lcm/channels.h"
#include "marionette/lcm/signing.h"
#include "marionette/lcm/validate.h"
#include "marionette/lcmt_driver_command.hpp"
#include "marionette/lcmt_driver_state.hpp"
#include "marionette/lcmt_driver_status.hpp"
#include "marionette/lcmt_object_poses.hpp"
#include "marionette/lcmt_sim_command.hpp"
#include "marionette/runtime/log_line.h"
#include "marionette/runtime/loop_clock.h"
#include "marionette/runtime/spsc_queue.h"
#include "marionette/runtime/triple_buffer.h"
#include "marionette/sim/mujoco_device.h"
#include "marionette/sim_driver/command_gate.h"
#include "marionette/sot/kinematics.h"

namespace marionette::sim_driver {

namespace {

using Clock = std::chrono::steady_clock;
constexpr double kDt = 1e-3;             // the control period [s]
constexpr int64_t kPeriodUs = 1000;      // the same in robot-clock microseconds
constexpr double kWaitFraction = 0.9;    // paced: wait for the answer this much of the period
constexpr int kRing = 64;                // cycles whose publish time is kept (late answers)
constexpr int kMaxRoundTripUs = 100000;  // the histogram's range (1 us bins); beyond: in max only
// Lockstep (--speed 0): before any command, the state goes out again this often (a controller
// that starts later gets it); after, an answer not there within kLockstepGiveUp was lost, and the
// cycle runs late (the clock moves on) rather than both ends waiting for ever. The controller may
// itself wait 5 s of wall time for a streamed reference before it answers.
constexpr auto kLockstepRepublish = std::chrono::milliseconds(500);
constexpr auto kLockstepGiveUp = std::chrono::seconds(10);
constexpr double kStatusRate = 10.0;  // DRIVER_STATUS [Hz]
// --realtime: SCHED_FIFO priorities of the loop and of the threads serving it (SIM_COMMAND,
// publisher), as the controller's.
constexpr int kLoopPriority = 80;
constexpr int kIoPriority = 40;

int64_t WallUs() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// What the loop shares with the publisher each cycle (fixed sizes: copied without allocation).
struct Snapshot {
  int64_t cycle = -1;  // -1: no cycle completed yet
  int64_t utime = 0;
  int64_t sequence = 0;  // of the last state published
  HoldReason reason = HoldReason::kNoCommandYet;
  int64_t command_age_us = 0;
  int64_t taken = 0, late = 0, refused = 0, holds = 0;
  double last_hold_reaction_ms = 0.0;
  double realtime_factor = 0.0;
  std::vector<double> object_poses;     // 7 per free object (x y z qw qx qy qz)
  std::vector<double> range_distances;  // one per range finder [m] (-1: nothing hit)
};

// One cycle (or one late answer) for the timing log and the round-trip statistics.
struct CycleTiming {
  int64_t sequence = 0;
  double round_trip_us = -1.0;  // < 0: no answer in the cycle
  bool late = false;            // the cycle ran without its own answer
  bool holding = false;
  bool late_answer = false;  // not a cycle: the answer to `sequence` came in a later cycle
};

}  // namespace

struct SimDriver::Impl {
  SimOptions options;
  controller::RobotInfo robot;
  sot::ModelPtr model;
  controller::StartedScene started;
  std::mt19937_64 range_noise{0};  // the range finders' noise (loop-owned; seeded)
  controller::DriverLayout layout;
  int substeps = 1;
  std::unique_ptr<sim::SceneMeasurement> measurement;
  std::unique_ptr<wire::Verifier> verifier;
  std::atomic<bool> stop{false};

  // The loop's LCM: DRIVER_STATE out, DRIVER_COMMAND in (handled by the loop thread itself).
  lcm::LCM loop_lcm;
  // SIM_COMMAND in (its own thread); DRIVER_STATUS, SIM_OBJECT_POSES, RANGE_FINDERS, CAMERA_HEAD
  // out.
  lcm::LCM side_lcm;
  const std::string state_channel = channels::kDriverState;

  // Loop-owned.
  controller::CommandReader reader;
  CommandGate gate;
  controller::MeasuredState state;
  lcmt_driver_state state_msg{};
  std::vector<uint8_t> state_buffer;
  int state_size = 0;
  lcmt_driver_command command_msg{};
  controller::JointCommand command;
  int64_t cycle = 0;
  std::array<Clock::time_point, kRing> published_at{};
  std::array<int64_t, kRing> published_sequence{};
  std::array<bool, kRing> answered{};
  double round_trip_us = -1.0;  // of this cycle's answer
  Clock::time_point last_publish{};
  int64_t refused = 0;
  Snapshot loop_state;
  std::atomic<int64_t> loop_utime{0};

  // Loop -> publisher / camera.
  std::unique_ptr<runtime::TripleBuffer<Snapshot>> snapshots;
  runtime::SpscQueue<CycleTiming> timings{1 << 15};
  std::atomic<int64_t> timings_lost{0};
  std::unique_ptr<controller::CameraStream> camera;
  // SIM_COMMAND thread -> loop.
  runtime::SpscQueue<controller::SimRequest> sim_requests{64};
  std::atomic<int64_t> sim_refused{0};

  // Refusals (written by the loop only when refusing, read by the publisher).
  std::mutex refusal_mutex;
  std::string last_refusal;

  // The publisher's statistics, read after it stopped.
  std::vector<int64_t> histogram;  // round trips, 1 us bins
  int64_t round_trips = 0;
  double max_round_trip_us = 0.0;

  explicit Impl(const SimOptions& o);
  void Loop();
  void ApplySimRequests();
  void PublishState();
  void WaitForCommand(Clock::time_point deadline, bool unpaced);
  void OnDriverCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void Refuse(const std::string& why);
  void SimCommandThread();
  void OnSimCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void RefuseSim(const std::string& category, const std::string& detail);
  void PublisherThread();
  void PublishStatus(const Snapshot& s);
  void PublishObjectPoses(const Snapshot& s);
  void PublishRangeFinders(const Snapshot& s);
  std::string Summary(double wall_s) const;
};

namespace {

controller::RobotInfo LoadRobot(const SimOptions& o) {
  try {
    return controller::FindRobot(o.robot, o.models_dir);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(e.what());
  }
}

sot::ModelPtr LoadRobotModel(const controller::RobotInfo& robot) {
  try {
    return sot::LoadModel(robot.urdf, sot::ParseBaseJoint(robot.base), robot.srdf);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot load robot '" + robot.name + "': " + e.what());
  }
}

}  // namespace

SimDriver::Impl::Impl(const SimOptions& o)
    : options(o),
      robot(LoadRobot(o)),
      model(LoadRobotModel(robot)),
      started(controller::StartScene(o.scene.empty() ? robot.mjcf : o.scene, *model, robot,
                                     controller::ReferencePosture(*model, robot),
                                     o.encoder_offsets)),
      layout(controller::MakeDriverLayout(*model, robot)),
      loop_lcm(o.lcm_url),
      side_lcm(o.lcm_url),
      reader(layout),
      gate(model->nq, model->nv, kPeriodUs, std::llround(o.command_timeout * 1e6)) {
  if (!loop_lcm.good() || !side_lcm.good())
    throw std::runtime_error("cannot open LCM at '" + o.lcm_url + "'");
  if (!options.key_file.empty())
    verifier = std::make_unique<wire::Verifier>(wire::LoadKey(options.key_file));
  sim::MujocoScene& scene = *started.scene;
  try {
    substeps = scene.SubstepsFor(kDt);
    measurement = std::make_unique<sim::SceneMeasurement>(&scene, robot.measured_bodies());
  } catch (const std::exception& e) {
    throw std::runtime_error(e.what());
  }
  // Sized once: the state, its message and its encoding; the command.
  state.q = started.q0;
  state.v = Eigen::VectorXd::Zero(model->nv);
  state.effort = Eigen::VectorXd::Zero(model->nv);
  state.wrenches.assign(6 * layout.wrench_bodies.size(), 0.0);
  controller::WriteState(layout, state, &state_msg);
  state_buffer.resize(state_msg.getEncodedSize());
  command.q = Eigen::VectorXd::Zero(model->nq);
  command.v = Eigen::VectorXd::Zero(model->nv);
  published_sequence.fill(-1);
  loop_state.object_poses.assign(7 * started.free_objects.size(), 0.0);
  loop_state.range_distances.assign(started.range_finders.size(), -1.0);
  snapshots = std::make_unique<runtime::TripleBuffer<Snapshot>>(loop_state);
  histogram.assign(kMaxRoundTripUs + 1, 0);
  last_refusal.reserve(1024);
  if (options.camera_rate > 0.0 && !robot.camera.empty()) {
    controller::CameraStreamOptions c;
    c.camera = robot.camera;
    c.camera_frame = robot.camera_frame;
    c.rate_hz = options.camera_rate;
    c.dt = kDt;
    c.width = options.camera_width;
    c.height = options.camera_height;
    c.noise_grey = options.camera_noise;
    c.depth_noise = options.depth_noise;
    c.log_prefix = "[sim]";
    camera = std::make_unique<controller::CameraStream>(&scene.model(), &side_lcm, c);
  }
}

// ---- the loop ----------------------------------------------------------------------------------

void SimDriver::Impl::ApplySimRequests() {
  sim::MujocoScene& scene = *started.scene;
  controller::SimRequest request;
  while (sim_requests.Pop(&request)) controller::ApplySimRequest(scene, request);
}

void SimDriver::Impl::PublishState() {
  loop_lcm.publish(state_channel, state_buffer.data(), state_size);
  last_publish = Clock::now();
}

void SimDriver::Impl::Refuse(const std::string& why) {
  ++refused;
  std::lock_guard<std::mutex> lock(refusal_mutex);
  const bool first = last_refusal.empty();
  last_refusal = why.substr(0, 1000);
  if (first || options.verbose) {
    runtime::LogLine(
        "[sim] DRIVER_COMMAND refused: ", last_refusal,
        first && !options.verbose ? " (the next ones are counted in DRIVER_STATUS)" : "");
  }
}

void SimDriver::Impl::OnDriverCommand(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  const Clock::time_point received = Clock::now();
  const wire::Verdict verdict =
      wire::Validate<lcmt_driver_command>(rbuf->data, rbuf->data_size, std::nullopt);
  if (!verdict.ok()) {
    Refuse(std::string(wire::ToString(verdict.refusal)) + ": " + verdict.detail);
    return;
  }
  const int size = static_cast<int>(rbuf->data_size);
  if (command_msg.decode(rbuf->data, 0, size) != size) {
    Refuse("undecodable: not a valid lcmt_driver_command");
    return;
  }
  std::string why;
  if (!reader.Read(command_msg, &command, &why)) {
    Refuse(why);
    return;
  }
  if (!gate.Offer(command, cycle, &why)) {
    Refuse(why);
    return;
  }
  const int slot = static_cast<int>(command.sequence % kRing);
  if (published_sequence[slot] != command.sequence || answered[slot]) return;
  answered[slot] = true;
  const double us =
      std::chrono::duration<double, std::micro>(received - published_at[slot]).count();
  if (command.sequence == cycle) {
    round_trip_us = us;
  } else if (!timings.Push(CycleTiming{command.sequence, us, false, false, true})) {
    timings_lost.fetch_add(1, std::memory_order_relaxed);
  }
}

void SimDriver::Impl::WaitForCommand(Clock::time_point deadline, bool unpaced) {
  const int fd = loop_lcm.getFileno();
  while (!stop.load(std::memory_order_relaxed) && !gate.HasCommandFor(cycle)) {
    const Clock::time_point now = Clock::now();
    std::chrono::nanoseconds wait = std::chrono::milliseconds(20);
    if (!unpaced) {
      if (now >= deadline) return;
      wait = std::min(wait, std::chrono::nanoseconds(deadline - now));
    } else if (gate.commands_taken() == 0 && now - last_publish >= kLockstepRepublish) {
      PublishState();  // no controller yet: one that starts later gets this state
    } else if (gate.commands_taken() > 0 && now - last_publish >= kLockstepGiveUp) {
      return;  // the answer was lost
    }
    const timespec timeout{static_cast<time_t>(wait.count() / 1000000000),
                           static_cast<long>(wait.count() % 1000000000)};
    pollfd p{fd, POLLIN, 0};
    if (ppoll(&p, 1, &timeout, nullptr) > 0) loop_lcm.handleTimeout(0);
  }
}

void SimDriver::Impl::Loop() {
  sim::MujocoScene& scene = *started.scene;
  const bool unpaced = options.speed == 0.0;
  const int64_t last_cycle =
      options.duration > 0.0 ? std::llround(options.duration / kDt) : int64_t{-1};
  const auto wait_window = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(unpaced ? 0.0 : kWaitFraction * kDt / options.speed));
  runtime::LoopClock clock(kDt, options.speed);
  for (cycle = 0; !stop.load(std::memory_order_relaxed) && (last_cycle < 0 || cycle < last_cycle);
       ++cycle) {
    // The cycle's window is counted from its deadline, not from when it started: a cycle that
    // starts late waits less, and the schedule keeps real time while commands do not come.
    const runtime::TickTiming timing = clock.WaitNextTick();
    const Clock::time_point start =
        Clock::now() - std::chrono::duration_cast<Clock::duration>(
                           std::chrono::duration<double, std::micro>(timing.lateness_us));
    const int64_t utime = cycle * kPeriodUs;
    loop_utime.store(utime, std::memory_order_relaxed);
    // 1. Perturbations enter at the start of the cycle.
    ApplySimRequests();
    // 2. The state now; efforts and wrenches of the last completed physics step.
    scene.Step1();
    scene.ReadRobotState(state.q, state.v);
    // The range finders of this state: mj_step1 computed them (Step2's extra physics steps would
    // leave those of an intermediate one).
    if (!started.range_finders.empty())
      controller::ReadRangeFinders(started.range_finders, scene.data(), &range_noise,
                                   &loop_state.range_distances);
    state.effort = measurement->effort();
    for (int i = 0; i < measurement->num_bodies(); ++i)
      for (int k = 0; k < 6; ++k) state.wrenches[6 * i + k] = measurement->wrench(i)[k];
    state.utime = utime;
    state.sequence = cycle;
    controller::WriteState(layout, state, &state_msg);
    state_size = state_msg.encode(state_buffer.data(), 0, static_cast<int>(state_buffer.size()));
    const int slot = static_cast<int>(cycle % kRing);
    published_sequence[slot] = cycle;
    answered[slot] = false;
    round_trip_us = -1.0;
    PublishState();
    published_at[slot] = last_publish;
    // 3. Its answer: until it comes (lockstep) or until the end of the cycle's window.
    WaitForCommand(start + wait_window, unpaced);
    if (stop.load(std::memory_order_relaxed) && unpaced && !gate.HasCommandFor(cycle)) break;
    // 4. The servos' targets and the physics step.
    gate.Decide(cycle, state.q);
    scene.WriteServoTargets(gate.q(), gate.v());
    scene.Step2(substeps);
    measurement->AfterStep();
    // 5. What the other threads publish. A cycle is late when it ran without its own answer
    // once commands had begun (before the first one, no controller is there to be late).
    const bool late = gate.reason() != HoldReason::kNoCommandYet && !gate.HasCommandFor(cycle);
    if (!timings.Push(CycleTiming{cycle, round_trip_us, late, gate.holding(), false}))
      timings_lost.fetch_add(1, std::memory_order_relaxed);
    Snapshot& s = loop_state;
    s.cycle = cycle;
    s.utime = utime;
    s.sequence = cycle;
    s.reason = gate.reason();
    s.command_age_us = gate.command_age_us();
    s.taken = gate.commands_taken();
    s.late = gate.commands_late();
    s.refused = refused;
    s.holds = gate.holds();
    s.last_hold_reaction_ms = gate.last_hold_reaction_ms();
    const double wall = clock.WallSeconds();
    s.realtime_factor = wall > 0.0 ? (cycle + 1) * kDt / wall : 0.0;
    const mjData& d = scene.data();
    for (size_t i = 0; i < started.free_object_ids.size(); ++i) {
      const int b = started.free_object_ids[i];
      for (int k = 0; k < 3; ++k) s.object_poses[7 * i + k] = d.xpos[3 * b + k];
      for (int k = 0; k < 4; ++k) s.object_poses[7 * i + 3 + k] = d.xquat[4 * b + k];
    }
    snapshots->write_slot() = s;  // same sizes: no allocation
    snapshots->Publish();
    if (camera && camera->Due(cycle)) camera->Offer(utime, d);
  }
  stop = true;
}

// ---- SIM_COMMAND ---------------------------------------------------------------------------

void SimDriver::Impl::RefuseSim(const std::string& category, const std::string& detail) {
  sim_refused.fetch_add(1, std::memory_order_relaxed);
  std::string shown = detail.substr(0, 1024);
  for (char& c : shown) {
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  }
  runtime::LogLine("[sim] SIM_COMMAND refused (", category, "): ", shown);
}

void SimDriver::Impl::SimCommandThread() {
  if (options.realtime) {
    runtime::LogLine("[sim] SIM_COMMAND thread ",
                     runtime::RequestThreadPriority(kIoPriority).message);
  }
  side_lcm.subscribe(channels::kSimCommand, &Impl::OnSimCommand, this);
  while (!stop.load(std::memory_order_relaxed)) side_lcm.handleTimeout(50);
}

void SimDriver::Impl::OnSimCommand(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  try {
    // The boundary, as the controller's Admit: the signature (with a key), the schema's bounds,
    // then lcm-gen's decoder.
    const void* data = rbuf->data;
    size_t size = rbuf->data_size;
    if (verifier) {
      std::string detail;
      const wire::SignatureCheck check =
          verifier->Verify(channels::kSimCommand, data, size, WallUs(), &size, &detail);
      if (check != wire::SignatureCheck::kAccepted) {
        RefuseSim(wire::ToString(check), detail);
        return;
      }
    }
    const wire::Verdict verdict =
        wire::Validate<lcmt_sim_command>(data, size, loop_utime.load(std::memory_order_relaxed));
    if (verdict.refusal == wire::Refusal::kTrailingBytes && wire::HasTrailer(data, size) &&
        verifier == nullptr) {
      RefuseSim("signed, no key",
                "a signed message, and marionette-sim has no key to check it (--key FILE or "
                "MARIONETTE_KEY)");
      return;
    }
    if (!verdict.ok()) {
      RefuseSim(wire::ToString(verdict.refusal), verdict.detail);
      return;
    }
    lcmt_sim_command msg;
    if (msg.decode(data, 0, static_cast<int>(size)) != static_cast<int>(size)) {
      RefuseSim("undecodable", "not a valid lcmt_sim_command");
      return;
    }
    auto read = controller::ReadSimCommand(msg, *started.scene, started.free_objects,
                                           started.free_object_ids);
    if (const auto* refusal = std::get_if<controller::SimCommandRefusal>(&read)) {
      RefuseSim(refusal->category, refusal->detail);
      return;
    }
    if (!sim_requests.Push(std::get<controller::SimRequest>(read))) {
      RefuseSim("queue full", "'" + msg.object_name + "' not changed");
    }
    if (options.verbose) runtime::LogLine("[sim] ", msg.command, " ", msg.object_name);
  } catch (const std::exception& e) {  // no exception leaves an LCM handler
    RefuseSim("internal error", e.what());
  }
}

// ---- publisher -------------------------------------------------------------------------------

void SimDriver::Impl::PublishStatus(const Snapshot& s) {
  lcmt_driver_status st{};
  st.utime = s.utime;
  st.sequence = s.sequence;
  st.robot_name = robot.name;
  st.holding = s.reason != HoldReason::kNone;
  switch (s.reason) {
    case HoldReason::kNone:
      break;
    case HoldReason::kNoCommandYet:
      st.reason = "no command yet";
      break;
    case HoldReason::kTimeout: {
      char buffer[64];
      std::snprintf(buffer, sizeof(buffer), "no command for %.1f ms", 1e-3 * s.command_age_us);
      st.reason = buffer;
      break;
    }
    case HoldReason::kRequested:
      st.reason = "hold requested";
      break;
  }
  st.commands_taken = s.taken;
  st.commands_late = s.late;
  st.commands_refused = s.refused;
  {
    std::lock_guard<std::mutex> lock(refusal_mutex);
    st.last_refusal = last_refusal;
  }
  st.holds = s.holds;
  st.last_hold_reaction_ms = s.last_hold_reaction_ms;
  st.realtime_factor = s.realtime_factor;
  side_lcm.publish(channels::kDriverStatus, &st);
}

void SimDriver::Impl::PublishObjectPoses(const Snapshot& s) {
  if (started.free_objects.empty()) return;
  const lcmt_object_poses poses =
      controller::SimulatorObjectPoses(started.free_objects, s.object_poses, s.utime);
  side_lcm.publish(channels::kSimObjectPoses, &poses);
}

void SimDriver::Impl::PublishRangeFinders(const Snapshot& s) {
  if (started.range_finders.empty()) return;
  const lcmt_range_finders ranges = controller::RangeFinderReadings(
      robot.name, started.range_finders.names, s.range_distances, s.utime);
  side_lcm.publish(channels::kRangeFinders, &ranges);
}

void SimDriver::Impl::PublisherThread() {
  if (options.realtime) {
    runtime::LogLine("[sim] publisher thread ",
                     runtime::RequestThreadPriority(kIoPriority).message);
  }
  const auto state_period = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(1.0 / options.state_rate));
  const auto status_period =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / kStatusRate));
  auto next_state = Clock::now(), next_status = Clock::now();
  std::vector<CycleTiming> all;  // every cycle, for --timing-log
  if (!options.timing_log.empty()) all.reserve(1 << 20);
  int64_t last_cycle = -2;
  const auto drain = [&] {
    CycleTiming t;
    while (timings.Pop(&t)) {
      if (t.round_trip_us >= 0.0) {
        ++histogram[std::min<int64_t>(kMaxRoundTripUs, std::llround(t.round_trip_us))];
        ++round_trips;
        max_round_trip_us = std::max(max_round_trip_us, t.round_trip_us);
      }
      if (!options.timing_log.empty() && !t.late_answer) all.push_back(t);
    }
  };
  bool running = true;
  while (running) {
    running = !stop.load(std::memory_order_acquire);
    if (running) std::this_thread::sleep_until(std::min(next_state, next_status));
    drain();
    snapshots->Fetch();
    const Snapshot& s = snapshots->read_slot();
    const auto now = Clock::now();
    if (now >= next_state || !running) {
      if (s.cycle != last_cycle && s.cycle >= 0) PublishObjectPoses(s);
      if (s.cycle != last_cycle && s.cycle >= 0) PublishRangeFinders(s);
      last_cycle = s.cycle;
      next_state = std::max(now, next_state + state_period);
    }
    if (now >= next_status || !running) {  // and a last one when the loop stopped
      PublishStatus(s);
      next_status = std::max(now, next_status + status_period);
    }
  }
  if (!options.timing_log.empty()) {
    if (FILE* f = std::fopen(options.timing_log.c_str(), "w")) {
      std::fprintf(f, "sequence,round_trip_us,late,holding\n");
      for (const CycleTiming& t : all) {
        if (t.round_trip_us >= 0.0)
          std::fprintf(f, "%lld,%.1f,%d,%d\n", static_cast<long long>(t.sequence), t.round_trip_us,
                       t.late ? 1 : 0, t.holding ? 1 : 0);
        else
          std::fprintf(f, "%lld,,%d,%d\n", static_cast<long long>(t.sequence), t.late ? 1 : 0,
                       t.holding ? 1 : 0);
      }
      std::fclose(f);
    } else {
      runtime::LogLine("[sim] cannot write the timing log ", options.timing_log);
    }
  }
}

std::string SimDriver::Impl::Summary(double wall_s) const {
  const auto percentile = [&](double p) -> double {
    if (round_trips == 0) return 0.0;
    const int64_t rank = std::max<int64_t>(1, static_cast<int64_t>(std::ceil(p * round_trips)));
    int64_t seen = 0;
    for (int i = 0; i <= kMaxRoundTripUs; ++i) {
      seen += histogram[i];
      if (seen >= rank) return i;
    }
    return kMaxRoundTripUs;
  };
  const Snapshot& s = snapshots->read_slot();
  const int64_t cycles = s.cycle + 1;
  char buffer[512];
  std::snprintf(buffer, sizeof(buffer),
                "[sim] stopped after %lld cycles (%.3f s of robot time in %.3f s, realtime factor "
                "%.2f): commands taken %lld, late %lld, refused %lld, holds %lld; round trip p50 "
                "%.0f us, p99 %.0f us, max %.0f us (%lld answers)",
                static_cast<long long>(cycles), cycles * kDt, wall_s,
                wall_s > 0.0 ? cycles * kDt / wall_s : 0.0, static_cast<long long>(s.taken),
                static_cast<long long>(s.late), static_cast<long long>(refused),
                static_cast<long long>(s.holds), percentile(0.5), percentile(0.99),
                max_round_trip_us, static_cast<long long>(round_trips));
  std::string out = buffer;
  if (const int64_t lost = sim_refused.load(); lost > 0)
    out += "; SIM_COMMAND refused " + std::to_string(lost);
  if (const int64_t lost = timings_lost.load(); lost > 0)
    out += "; " + std::to_string(lost) + " timings lost";
  return out;
}

// ---- SimDriver -------------------------------------------------------------------------------

SimDriver::SimDriver(const SimOptions& options) : impl_(std::make_unique<Impl>(options)) {}
SimDriver::~SimDriver() = default;

void SimDriver::Stop() {
  if (impl_) impl_->stop.store(true, std::memory_order_relaxed);
}

int SimDriver::Run() {
  Impl& c = *impl_;
  std::thread sim_commands(&Impl::SimCommandThread, &c);
  std::thread publisher(&Impl::PublisherThread, &c);
  if (c.camera) c.camera->Start();
  // The loop at the top priority, asked for once the other threads exist (they would inherit
  // it); the camera thread runs at SCHED_IDLE.
  if (c.options.realtime) {
    runtime::LogLine("[sim] loop thread ", runtime::RequestRealtime(kLoopPriority).message);
  }
  // Subscribed before the first state goes out: its answer cannot be missed. After the request
  // above: LCM's receiving thread, started by the first subscription, inherits the loop's
  // priority (the command's path from the socket to the loop is real-time end to end).
  c.loop_lcm.subscribe(channels::kDriverCommand, &Impl::OnDriverCommand, &c);
  char timeout[32], speed[32];
  std::snprintf(timeout, sizeof(timeout), "%.1f ms", c.options.command_timeout * 1e3);
  std::snprintf(speed, sizeof(speed), "speed %g", c.options.speed);
  runtime::LogLine(
      "[sim] ", c.robot.name, " in ", c.options.scene.empty() ? c.robot.mjcf : c.options.scene,
      ": ", c.layout.joints.size(), " joints, ", c.layout.wrench_bodies.size(), " wrench bodies, ",
      c.started.free_objects.size(), " free objects; 1 kHz, ",
      c.options.speed == 0.0 ? "lockstep (speed 0)" : speed, ", command timeout ", timeout,
      ", camera ", c.camera ? std::to_string(c.options.camera_rate) + " Hz" : std::string("off"),
      "; SIM_COMMAND ",
      c.verifier ? "signed only (key " + c.options.key_file + ")"
                 : std::string("unsigned (no key)"));
  const Clock::time_point start = Clock::now();
  c.Loop();
  const double wall = std::chrono::duration<double>(Clock::now() - start).count();
  if (c.camera) c.camera->Stop();
  publisher.join();
  sim_commands.join();
  runtime::LogLine(c.Summary(wall));
  return 0;
}

}  // namespace marionette::sim_driver
