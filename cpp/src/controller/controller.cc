// marionette-controller: start-up, the persistent graph, the 1 kHz loop, the command line.
#include <chrono>
#include <optional>
#include <thread>
#include <tuple>

#include "controller_impl.h"
#include "marionette/controller/command_line.h"

namespace marionette::controller {

namespace {

// The world poses (x y z, qw qx qy qz) of the scene's free bodies ``ids`` into ``poses`` (7 each).
void ReadObjectPoses(const mjData& d, const std::vector<int>& ids, std::vector<double>* poses) {
  for (size_t i = 0; i < ids.size(); ++i) {
    const int b = ids[i];
    for (int k = 0; k < 3; ++k) (*poses)[7 * i + k] = d.xpos[3 * b + k];
    for (int k = 0; k < 4; ++k) (*poses)[7 * i + 3 + k] = d.xquat[4 * b + k];
  }
}

}  // namespace

Controller::Impl::Impl(const ControllerOptions& o, const std::string* first_driver_state)
    : options(o), lcm(o.lcm_url) {
  if (!lcm.good()) throw std::runtime_error("cannot open LCM at '" + o.lcm_url + "'");
  if (!options.key_file.empty())
    verifier = std::make_unique<wire::Verifier>(wire::LoadKey(o.key_file));
  if (!options.journal_file.empty()) {
    black_box = std::make_unique<lcm::LogFile>(options.journal_file, "w");
    if (!black_box->good())
      throw std::runtime_error("cannot write the journal '" + options.journal_file + "'");
  }
  try {
    robot = FindRobot(options.robot, options.models_dir);
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error(e.what());
  }
  try {
    model = sot::LoadModel(robot.urdf, sot::ParseBaseJoint(robot.base), robot.srdf);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot load robot '" + robot.name + "': " + e.what());
  }
  Eigen::VectorXd q0 = ReferencePosture(*model, robot);
  {  // the 1-dof joints, as the driver protocol lays them out (one definition for both)
    const DriverLayout layout = MakeDriverLayout(*model, robot);
    joint_names = layout.joints;
    joint_q = layout.idx_q;
    joint_v = layout.idx_v;
  }
  if (options.backend == "mujoco") {
    StartedScene started = StartScene(options.scene.empty() ? robot.mjcf : options.scene, *model,
                                      robot, q0, options.encoder_offsets);
    scene = std::move(started.scene);
    q0 = started.q0;
    free_objects = std::move(started.free_objects);
    free_object_ids = std::move(started.free_object_ids);
    range_finders = std::move(started.range_finders);
  } else if (options.backend == "driver") {
    driver_layout = std::make_unique<DriverLayout>(MakeDriverLayout(*model, robot));
    std::string first;
    if (first_driver_state != nullptr) {
      first = *first_driver_state;
    } else {
      // The loop's own instance subscribes in Run(), once the loop thread has its priority: LCM
      // starts its receiving thread at the first subscription, and that thread inherits it.
      driver_lcm = std::make_unique<lcm::LCM>(options.lcm_url);
      lcm::LCM waiting(options.lcm_url);
      if (!driver_lcm->good() || !waiting.good())
        throw std::runtime_error("cannot open LCM at '" + options.lcm_url + "' for the driver");
      runtime::LogLine("[controller] waiting for ", robot.name, "'s driver on DRIVER_STATE (",
                       driver_layout->joints.size(), " joints: ", JointList(*driver_layout), ")");
      first = WaitFirstState(waiting, *driver_layout, /*timeout_s=*/0.0);
    }
    first_driver_state_bytes = first;
    first_driver_state_read = std::make_unique<MeasuredState>(
        ReadState(first, *driver_layout));  // throws: a replay's log that does not fit
    q0 = first_driver_state_read->q;
  } else if (options.backend != "kinematic") {
    throw std::runtime_error("unknown backend '" + options.backend +
                             "' (mujoco, kinematic, driver)");
  }
  BuildPersistentGraph(q0);
  if (driver_device) {  // the first state is tick 0's
    lcm::ReceiveBuffer rbuf{first_driver_state_bytes.data(),
                            static_cast<uint32_t>(first_driver_state_bytes.size()), 0};
    OnDriverState(&rbuf, channels::kDriverState);
  }
}

void Controller::Impl::BuildPersistentGraph(const Eigen::VectorXd& q0) {
  graph::GraphBuilder b;
  command = &b.Add<sot::KinematicDevice>("command", model, q0);
  robot_model = &b.Add<sot::RobotModel>("robot", model);
  safety = &b.Add<SafetyFilter>("safety", *model, kDt, options.velocity_scale);
  // What the safety filter gets while no controller runs: zero, and nobody may change that.
  auto& idle =
      b.Add<graph::VectorConstant>("idle", Eigen::VectorXd::Zero(model->nv), /*settable=*/false);
  b.Connect(idle.out_output(), safety->velocity_input());
  b.Connect(safety->velocity_output(), command->command_input());
  if (driver_layout) {
    driver_device = &b.Add<DriverDevice>("device", *driver_layout, *first_driver_state_read,
                                         driver_lcm.get(), kMaxDriverClockStepUs);
    device = driver_device;
  } else if (scene) {
    device = &b.Add<sim::MujocoDevice>("device", scene.get(), robot.measured_bodies(), kDt);
  }
  if (device) {
    const int base_nq = robot.base == "free_flyer" ? 7 : robot.base == "planar" ? 4 : 0;
    measured_base = &b.Add<MeasuredBase>("measured_base", model->nq, base_nq);
    b.Connect(command->configuration_output(), measured_base->q_command_input());
    b.Connect(device->q_output(), measured_base->q_measured_input());
    b.Connect(command->configuration_output(), device->q_command_input());
    b.Connect(safety->velocity_output(), device->v_command_input());
    q_kinematics = &measured_base->q_output();
  } else {
    q_kinematics = &command->configuration_output();
  }
  b.Connect(*q_kinematics, robot_model->configuration_input());
  b.Connect(*q_kinematics, safety->q_input());
  graph = b.Build();
  graph->SetProfiling(options.profiling);
  overran.reserve(kMaxEntities);
  overrun_hold_ticks = options.overrun_hold_ticks;
  TimingTable model_table;
  model_table.windows.resize(kMaxEntities);
  model_table.budget_us.resize(kMaxEntities);
  model_table.overruns.resize(kMaxEntities);
  timing_tables = std::make_unique<runtime::TripleBuffer<TimingTable>>(model_table);
  shared_q = q0;
  for (const std::string& body : robot.contact_bodies) {
    if (!model->existFrame(body)) continue;
    contact_frames.push_back(sot::MakeFrameRef(*model, body, "contact body"));
    soles.push_back(body);
  }
  factory = std::make_unique<ControllerFactory>(
      model,
      ControllerSockets{&robot_model->kinematics_output(), &safety->velocity_input(),
                        &command->velocity_output(),
                        device ? &device->effort_output() : nullptr,  // gripper admittance
                        device ? &device->q_output() : nullptr},
      /*default_gain=*/2.0, HeldBaseVelocities(robot));

  Snapshot model_snapshot;
  model_snapshot.q = q0;
  model_snapshot.v = Eigen::VectorXd::Zero(model->nv);
  model_snapshot.q_command = q0;
  model_snapshot.q_kinematics = q0;
  model_snapshot.v_command = Eigen::VectorXd::Zero(model->nv);
  model_snapshot.effort = Eigen::VectorXd::Zero(model->nv);
  model_snapshot.wrenches.assign(6 * robot.measured_bodies().size() * (device ? 1 : 0), 0.0);
  model_snapshot.object_poses.assign(7 * free_objects.size(), 0.0);
  if (scene)  // where the scene starts them: published before the first tick, never zeros
    ReadObjectPoses(scene->data(), free_object_ids, &model_snapshot.object_poses);
  model_snapshot.range_distances.assign(range_finders.size(), -1.0);
  loop_state = model_snapshot;
  snapshots = std::make_unique<runtime::TripleBuffer<Snapshot>>(model_snapshot);
  active_streams.reserve(kMaxTasks);
  if (scene && options.camera_rate > 0.0 && !robot.camera.empty()) {
    CameraStreamOptions o;
    o.camera = robot.camera;
    o.camera_frame = robot.camera_frame;
    o.rate_hz = options.camera_rate;
    o.dt = kDt;
    o.width = options.camera_width, o.height = options.camera_height;
    o.noise_grey = options.camera_noise, o.depth_noise = options.depth_noise;
    camera = std::make_unique<CameraStream>(&scene->model(), &lcm, o);
  }
}

void Controller::Impl::Reject(const std::string& channel, const std::string& category,
                              const std::string& detail) {
  // The detail quotes what was sent: printable, and short enough for the status's bounds.
  constexpr size_t kMaxDetail = 1024;
  std::string shown = detail.substr(0, kMaxDetail);
  for (char& c : shown) {
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  }
  if (detail.size() > kMaxDetail) shown += "...";
  std::lock_guard<std::mutex> lock(stats_mutex);
  ++rejections[channel + ": " + category];
  ++num_rejected;
  last_rejection = channel + ": " + shown;
  if (options.verbose) runtime::LogLine("[controller] rejected ", last_rejection);
}

// ---- the loop ----------------------------------------------------------------------------------

void Controller::Impl::LoopTick(const graph::Tick& t, runtime::LoopClock& clock) {
  // Inputs enter at the start of the tick, each journaled with the tick that consumed it.
  SimRequest request;
  while (scene && sim_requests.Pop(&request)) {
    Journal(t.index, 3, request.hash);
    ApplySimRequest(*scene, request);
  }
  std::array<int64_t, 64> set_hashes;
  const int num_sets = service.ApplySets(set_hashes.data(), static_cast<int>(set_hashes.size()));
  for (int i = 0; i < num_sets; ++i) Journal(t.index, 4, set_hashes[i]);
  ApplyCommand(t);
  safety->mode_input().SetValue(static_cast<int>(mode));
  if (driver_device) {
    ApplyDriverHold(t);
    Journal(t.index, kDriverStateChannel, driver_state_hash);
  }
  if (device) device->Read(t);
  // The range finders of the state just measured: mj_step1 (in Read) computed them with the
  // positions q was read from; Write's extra physics steps, when the MuJoCo timestep is shorter
  // than the tick, would leave those of an intermediate state.
  if (!range_finders.empty())
    ReadRangeFinders(range_finders, scene->data(), &range_noise, &loop_state.range_distances);
  graph->Evaluate(t);
  for (ReferenceStream* stream : active_streams) {
    for (int i = 0; i < stream->drained_count(); ++i) Journal(t.index, 1, stream->drained_hash(i));
  }
  if (active != nullptr && active->walk_steps != nullptr) {
    const walk::FootstepManager& steps = *active->walk_steps;
    for (int i = 0; i < steps.drained_count(); ++i)
      Journal(t.index, kFootstepPlanChannel, steps.drained_hash(i));
  }
  if (safety->non_finite_output().Eval(t)) {
    ++loop_state.non_finite_ticks;
    if (mode == ControlMode::kRun) {
      mode = ControlMode::kHold;
      loop_state.reason = Reason::kNonFinite;
    }
  }
  if (safety->num_clamped_output().Eval(t) > 0) ++loop_state.clamped_ticks;
  Watchdog(t);
  CheckBudgets(t);
  HoldOnSilence(t);
  DecideSwitch(t);
  if (driver_device) driver_device->set_command_mode(mode == ControlMode::kEstop ? 1 : 0);
  if (device) device->Write(t);
  FillSnapshot(t, clock);
  service.Sample(t.index, TickUs(t));
  if ((t.index + 1) % timing_window_ticks == 0) CopyTimings(t);
}

void Controller::Impl::CheckBudgets(const graph::Tick& t) {
  if (replaying) {  // the recorded decision, not this machine's timing
    if (replay_budget_hold >= 0 && mode == ControlMode::kRun) {
      const bool engage = (replay_budget_hold & kBudgetHoldEngaged) != 0;
      const bool engaged = engage && EngageHoldController(t, Reason::kBudget) == Engage::kEngaged;
      Journal(t.index, kBudgetHoldChannel,
              replay_budget_hold & ~(engage && !engaged ? kBudgetHoldEngaged : 0));
      if (!engaged) mode = ControlMode::kHold;
      loop_state.reason = Reason::kBudget;
      loop_state.reason_index = static_cast<int>(replay_budget_hold & (kBudgetHoldEngaged - 1));
    }
    replay_budget_hold = -1;
    return;
  }
  if (graph->LastOverruns(&overran) == 0) return;
  for (const graph::Entity* e : overran) {
    const auto& entities = graph->entities();
    for (size_t i = 0; i < entities.size(); ++i) {
      if (entities[i].get() != e) continue;
      // One event when an overrun starts, not one per tick.
      const int64_t overruns = e->timing().consecutive_overruns;
      if (overruns == 1) overrun_events.Push({t.index, static_cast<int>(i)});
      if (overruns < overrun_hold_ticks || mode != ControlMode::kRun) continue;
      // First the hold controller (balance + posture); when it is not armed (a swap pending, it
      // is the one overrunning, or it failed to build), zero velocity. A busy lease is retried
      // next tick, for as many ticks again at most.
      const Engage engage = EngageHoldController(t, Reason::kBudget);
      if (engage == Engage::kRetry && overruns < 2 * overrun_hold_ticks) return;
      const bool engaged = engage == Engage::kEngaged;
      Journal(t.index, kBudgetHoldChannel,
              static_cast<int64_t>(i) + (engaged ? kBudgetHoldEngaged : 0));
      if (!engaged) mode = ControlMode::kHold;
      loop_state.reason = Reason::kBudget;
      loop_state.reason_index = static_cast<int>(i);
      loop_state.reason_value = static_cast<double>(overruns);
      return;  // engaged: `overran` points into the replaced topology
    }
  }
}

Controller::Impl::Engage Controller::Impl::EngageHoldController(const graph::Tick& t, Reason why) {
  if (hold_state.load(std::memory_order_acquire) != kHoldArmed) return Engage::kUnavailable;
  int free = 0;
  if (!graph_lease.compare_exchange_strong(free, 2, std::memory_order_acquire))
    return Engage::kRetry;
  BuiltController* hold = armed_hold;
  hold->HoldCurrent(robot_model->kinematics_output().Eval(t));
  if (!graph->Apply(
          hold->edit.get())) {  // built against another version: the LCM thread rebuilds it
    hold_state.store(kHoldStale, std::memory_order_release);
    graph_lease.store(0, std::memory_order_release);
    return Engage::kUnavailable;
  }
  service.Invalidate();  // watched entities of the old controller are gone
  active = hold;
  active_streams.clear();
  ++loop_state.switches;
  loop_state.active_id = hold->id;
  hold_engaged_tick = t.index;
  hold_engaged_why = why;
  hold_state.store(kHoldEngaged, std::memory_order_release);
  graph_lease.store(0, std::memory_order_release);
  return Engage::kEngaged;
}

void Controller::Impl::CopyTimings(const graph::Tick& t) {
  TimingTable& table = timing_tables->write_slot();
  const auto& entities = graph->entities();
  table.graph_version = graph->version();
  table.utime = TickUs(t);
  table.num_entities = std::min<int>(kMaxEntities, static_cast<int>(entities.size()));
  table.window_ticks = timing_window_ticks;
  for (int i = 0; i < table.num_entities; ++i) {
    graph::EntityTiming& timing = entities[i]->mutable_timing();
    table.windows[i] = timing.window;
    table.budget_us[i] = 1e-3 * timing.budget_ns;
    table.overruns[i] = timing.overruns;
    timing.window.Clear();
  }
  timing_tables->Publish();
}

void Controller::Impl::Record(const std::string& channel, const void* data, size_t size,
                              int64_t utime) {
  std::lock_guard<std::mutex> lock(black_box_mutex);
  lcm::LogEvent event;
  event.eventnum = black_box_events++;
  event.timestamp = utime;
  event.channel = channel;
  event.datalen = static_cast<int32_t>(size);
  event.data = const_cast<void*>(data);
  if (black_box->writeEvent(&event) != 0) records_lost.fetch_add(1, std::memory_order_relaxed);
}

void Controller::Impl::Journal(int64_t tick, int channel, int64_t hash) {
  // Full: the publisher is behind; the entry is lost and counted (a replay says it cannot be
  // exact).
  if (!journal.Push(JournalEntry{tick, channel, hash}))
    journal_lost.fetch_add(1, std::memory_order_relaxed);
}

std::string Controller::Impl::MotionConfig() const {
  char scale[32];
  std::snprintf(scale, sizeof(scale), "%.17g", options.velocity_scale);
  std::string offsets;
  for (const auto& [joint, offset] : options.encoder_offsets) {
    char value[64];
    std::snprintf(value, sizeof(value), "%.17g", offset);
    offsets += (offsets.empty() ? " --encoder-offsets " : ",") + joint + "=" + value;
  }
  return "--robot " + options.robot + " --backend " + options.backend +
         (options.scene.empty() ? std::string() : " --scene " + options.scene) +
         " --velocity-scale " + scale + offsets;
}

void Controller::Impl::ApplyCommand(const graph::Tick& t) {
  const auto c = static_cast<Command>(command_request.exchange(static_cast<int>(Command::kNone)));
  if (c != Command::kNone) Journal(t.index, 2, command_hash.load(std::memory_order_acquire));
  switch (c) {
    case Command::kNone:
      return;
    case Command::kHold:
      if (mode == ControlMode::kRun) mode = ControlMode::kHold;
      break;
    case Command::kResume:
      if (mode == ControlMode::kHold && active != nullptr) mode = ControlMode::kRun;
      break;
    case Command::kEstop:
      mode = ControlMode::kEstop;
      break;
    case Command::kResetEstop:
      if (mode == ControlMode::kEstop) mode = ControlMode::kHold;
      break;
    case Command::kStop:
      stop = true;
      break;
  }
  loop_state.reason = Reason::kCommand;
  loop_state.reason_index = static_cast<int>(c);
}

void Controller::Impl::Watchdog(const graph::Tick& t) {
  if (mode != ControlMode::kRun || active == nullptr) return;
  for (size_t i = 0; i < active_streams.size(); ++i) {
    ReferenceStream* s = active_streams[i];
    const double age = s->age_output().Eval(t);
    if (!s->ended_output().Eval(t) && age > active->reference_timeout) {
      mode = ControlMode::kHold;
      loop_state.reason = Reason::kWatchdog;
      loop_state.reason_index = static_cast<int>(i);
      loop_state.reason_value = age;
      return;
    }
  }
}

void Controller::Impl::HoldOnSilence(const graph::Tick& t) {
  // Live: the LCM thread saw the supervisor silent; a replay: the journal says this tick held.
  const bool silent =
      replaying ? replay_silence_hold >= 0 : silence_request.load(std::memory_order_acquire);
  if (!silent) return;
  const bool supervised =
      mode == ControlMode::kRun && active != nullptr && active->id != kHoldControllerId &&
      switch_state.load(std::memory_order_acquire) != static_cast<int>(SwitchState::kPosted);
  if (!replaying && !supervised) {  // holding already, or a new spec is about to be decided
    silence_request.store(false, std::memory_order_relaxed);
    silence_retries = 0;
    return;
  }
  bool engaged = false;
  if (replaying) {
    engaged = replay_silence_hold == 1 &&
              EngageHoldController(t, Reason::kSupervisorSilent) == Engage::kEngaged;
    replay_silence_hold = -1;
  } else {
    // The hold controller first; a busy lease is retried for a few ticks, then zero velocity.
    const Engage engage = EngageHoldController(t, Reason::kSupervisorSilent);
    if (engage == Engage::kRetry && ++silence_retries < kSilenceEngageRetries) return;
    engaged = engage == Engage::kEngaged;
    silence_request.store(false, std::memory_order_relaxed);
    silence_retries = 0;
  }
  Journal(t.index, kSilenceHoldChannel, engaged ? 1 : 0);
  if (!engaged) mode = ControlMode::kHold;
  loop_state.reason = Reason::kSupervisorSilent;
  loop_state.reason_value = silence_seconds.load(std::memory_order_relaxed);
}

// ---- the robot's driver (driver backend)
// ---------------------------------------------------------

bool Controller::Impl::WaitDriverState(double timeout_s) {
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(timeout_s));
  while (!driver_device->has_state() && !stop) {
    const auto left =
        std::chrono::duration_cast<std::chrono::microseconds>(deadline - Clock::now());
    if (left.count() <= 0) break;
    // LCM waits in whole milliseconds: at least 1, at most 100 (a stop is seen within that).
    driver_lcm->handleTimeout(static_cast<int>(std::clamp<int64_t>(left.count() / 1000, 1, 100)));
  }
  if (driver_device->has_state()) {
    driver_silent = false;
    last_driver_state = Clock::now();
    return true;
  }
  if (!driver_silent && !stop) {  // once per silence; the status says how long since the last
    driver_silent = true;
    driver_hold = 1;
    ShowDriverHold(std::chrono::duration<double>(Clock::now() - last_driver_state).count());
  }
  return false;
}

void Controller::Impl::OnDriverState(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  DriverDevice::Refusal refusal;
  if (driver_device->Offer(rbuf->data, rbuf->data_size, &refusal)) {
    driver_state_hash = Fnv1a(rbuf->data, rbuf->data_size);
    if (black_box && !replaying) {  // copied within the slots' capacity: no allocation
      const auto* bytes = static_cast<const uint8_t*>(rbuf->data);
      if (!state_records) {  // the first state (start-up) sizes the slots
        const size_t slot = std::max<size_t>(4096, 2 * rbuf->data_size);
        state_records = std::make_unique<runtime::SpscQueue<std::vector<uint8_t>>>(
            kStateRecords, std::vector<uint8_t>(slot));
        state_record_scratch.reserve(slot);
      }
      if (rbuf->data_size > state_record_scratch.capacity()) {
        records_lost.fetch_add(1, std::memory_order_relaxed);
      } else {
        state_record_scratch.assign(bytes, bytes + rbuf->data_size);
        if (!state_records->Push(state_record_scratch))
          records_lost.fetch_add(1, std::memory_order_relaxed);
      }
    }
    return;
  }
  if (!driver_refusals.Push(DriverRefusalEvent{refusal.category, refusal.detail}))
    driver_refusals_lost.fetch_add(1, std::memory_order_relaxed);
  if (replaying) return;  // the journal says when the live run held
  driver_hold = 2;
  ShowDriverHold(0.0);
}

void Controller::Impl::ShowDriverHold(double seconds) {
  // Between ticks: the status says it now; the next tick journals it (ApplyDriverHold).
  if (mode == ControlMode::kRun) mode = ControlMode::kHold;
  loop_state.reason = driver_hold == 1 ? Reason::kDriverSilent : Reason::kDriverRefused;
  loop_state.reason_value = seconds;
  loop_state.mode = static_cast<int>(mode);
  snapshots->write_slot() = loop_state;
  snapshots->Publish();
}

void Controller::Impl::ApplyDriverHold(const graph::Tick& t) {
  if (driver_hold == 0) return;
  Journal(t.index, kDriverHoldChannel, driver_hold);
  if (mode == ControlMode::kRun) mode = ControlMode::kHold;
  loop_state.reason = driver_hold == 1 ? Reason::kDriverSilent : Reason::kDriverRefused;
  driver_hold = 0;
}

void Controller::Impl::DecideSwitch(const graph::Tick& t) {
  if (switch_state.load(std::memory_order_acquire) != static_cast<int>(SwitchState::kPosted))
    return;
  BuiltController* next = posted;
  Journal(t.index, 0, posted_hash);
  Journal(t.index, kBuildTickChannel, posted_build_tick);
  // "Hold where it is" references take the values of this very tick.
  next->HoldCurrent(robot_model->kinematics_output().Eval(t));
  // Agimus's start check (§3.2.5.2), real-time safe here: the new stack's solution at this very
  // tick against the command being applied, on the joints the robot is commanded (ROBOT_COMMAND,
  // the driver's layout). A free-flyer's six velocities drive nothing: a walking stack keeps
  // "commanding" the base toward soles that landed a few mm from their references, and a stack
  // holding the measured soles would be refused for a motion no motor makes.
  const Eigen::VectorXd& v_next = next->unblended_velocity->Eval(t);
  const Eigen::VectorXd& v_now = safety->velocity_output().Eval(t);
  double jump = 0.0;
  int jumped = -1;
  for (const int i : joint_v) {
    const double d = std::abs(v_next[i] - v_now[i]);
    if (jumped < 0 || d > jump || !std::isfinite(d)) jump = d, jumped = i;
  }
  if (!std::isfinite(jump)) jump = std::numeric_limits<double>::infinity();
  if (mode == ControlMode::kEstop || !(jump <= next->max_switch_velocity_jump) ||
      !graph->Apply(next->edit.get())) {
    refused_jump = mode == ControlMode::kEstop ? -1.0 : jump;
    refused_jump_v = jumped;
    decided_tick = t.index;
    ++loop_state.refused_switches;
    switch_state.store(static_cast<int>(SwitchState::kRefused), std::memory_order_release);
    return;
  }
  service.Invalidate();  // watched entities of the old controller are gone
  active = next;
  active_streams.clear();
  for (auto& [name, stream] : next->streams) active_streams.push_back(stream);
  ++loop_state.switches;
  if (mode == ControlMode::kHold) mode = ControlMode::kRun;
  loop_state.reason = Reason::kControllerAccepted;
  loop_state.active_id = next->id;
  decided_tick = t.index;
  switch_state.store(static_cast<int>(SwitchState::kApplied), std::memory_order_release);
}

void Controller::Impl::FillSnapshot(const graph::Tick& t, const runtime::LoopClock& clock) {
  Snapshot& s = loop_state;
  s.tick = t.index;
  s.utime = TickUs(t);
  // The hold controller runs (the safety filter passes its command) but the robot is holding.
  const bool hold_controller_running =
      mode == ControlMode::kRun && active != nullptr && active->id == kHoldControllerId;
  s.mode = static_cast<int>(hold_controller_running ? ControlMode::kHold : mode);
  s.q = q_kinematics->value();
  s.q_kinematics = q_kinematics->value();
  s.v = device ? device->v_output().value() : command->velocity_output().value();
  s.q_command = command->configuration_output().value();
  s.v_command = safety->velocity_output().value();
  if (device) {
    s.q = device->q_output().value();
    s.effort = device->effort_output().value();
    for (size_t i = 0; i < s.wrenches.size() / 6; ++i) {
      for (int k = 0; k < 6; ++k)
        s.wrenches[6 * i + k] = device->wrench_output(static_cast<int>(i)).value()[k];
    }
    if (scene) ReadObjectPoses(scene->data(), free_object_ids, &s.object_poses);  // driver: none
  }
  s.num_tasks = 0;
  if (active != nullptr) {
    s.num_tasks = std::min<int>(kMaxTasks, static_cast<int>(active->task_errors.size()));
    for (int i = 0; i < s.num_tasks; ++i) s.task_error[i] = active->task_errors[i]->Eval(t);
  }
  s.deadline_misses = clock.deadline_misses();
  const double wall = clock.WallSeconds();
  s.realtime_factor = wall > 0.0 ? t.time / wall : 0.0;
  s.walking = active != nullptr && active->walk_steps != nullptr;
  if (s.walking) FillWalkStatus(t, &s);
  snapshots->write_slot() = s;  // same sizes: no allocation
  snapshots->Publish();
  if (camera && camera->Due(t.index)) camera->Offer(TickUs(t), scene->data());
}

// ---- unpaced pacing ---------------------------------------------------------------------------

namespace {

// Unpaced (--speed 0) controller time is simulated: it advances as fast as the loop computes (~10x
// real time) and outran the process streaming a reference (a few seconds of controller time ahead)
// whenever that process was slowed down; the watchdog, a real-time safety device, then held the
// robot for a streamer that was merely late (or the first chunk of a step arrived already in the
// past). So the unpaced loop starts no tick that a running stream does not cover: it waits for its
// first or next chunk (or a command, a swap, a stop), and only after kStarvedWallTimeout of wall
// time without one lets the clock go on, and the watchdog fire: the streaming process is gone.
// Covering is judged on what the chunks that came say, taken in before the tick: a chunk replaces
// a stream's future from its start, and a supervisor re-sending a corrected stretch in pieces
// from where it last saw the clock (1.5 s of controller time behind it, unpaced) cut the stream
// short with its first piece; a chunk merely waiting in the queue let the tick go on, and the
// watchdog held the robot 64 ms of wall time before the next piece came.
constexpr auto kStarvedWallTimeout = std::chrono::seconds(5);
constexpr auto kStarvedPoll = std::chrono::microseconds(100);

class ReferenceWait {
 public:
  // Before tick `t`: returns once no running stream is starved at t, an input is pending, or the
  // timeout of the current starvation has passed.
  void Before(Controller::Impl& c, const graph::Tick& t) {
    if (!Starved(c, t)) {
      starved_ = false;
      return;
    }
    if (!starved_) since_ = std::chrono::steady_clock::now();
    starved_ = true;
    const auto deadline = since_ + kStarvedWallTimeout;
    while (Starved(c, t) && !InputPending(c) && std::chrono::steady_clock::now() < deadline)
      std::this_thread::sleep_for(kStarvedPoll);
  }

 private:
  static bool Starved(Controller::Impl& c, const graph::Tick& t) {
    if (c.mode != ControlMode::kRun || c.active == nullptr) return false;
    for (ReferenceStream* s : c.active_streams) {
      s->PollBeforeTick();
      if (s->Starved(TickUs(t))) return true;
    }
    return false;
  }
  static bool InputPending(const Controller::Impl& c) {
    return c.stop ||
           c.command_request.load(std::memory_order_acquire) != static_cast<int>(Command::kNone) ||
           c.switch_state.load(std::memory_order_acquire) == static_cast<int>(SwitchState::kPosted);
  }
  bool starved_ = false;
  std::chrono::steady_clock::time_point since_{};  // the starvation began (wall), when starved_
};

}  // namespace

// ---- Controller -----------------------------------------------------------------------------

Controller::Controller(const ControllerOptions& options) : impl_(std::make_unique<Impl>(options)) {}
Controller::~Controller() { Stop(); }

void Controller::Stop() {
  if (impl_) impl_->stop = true;
}

int Controller::Run() {
  Impl& c = *impl_;
  // Subscribed before anything is published: whoever sees our first status can talk to us.
  c.lcm.subscribe(channels::kControllerSpec, &Impl::OnSpec, &c);
  // LCM queues 30 messages per subscription by default and drops the rest silently: a streamer's
  // 4 s look-ahead of 20 chunks per task overflowed it when the LCM thread was starved of CPU.
  c.lcm.subscribe(channels::kTaskReference, &Impl::OnReference, &c)
      ->setQueueCapacity(kReferenceQueueMessages);
  c.lcm.subscribe(channels::kCommand, &Impl::OnCommand, &c)
      ->setQueueCapacity(kCommandQueueMessages);
  // SIM_COMMAND is the simulator's: with a driver, marionette-sim's (or nobody's, on a robot); the
  // kinematic backend refuses it, counted ("no simulator").
  if (!c.driver_device) c.lcm.subscribe(channels::kSimCommand, &Impl::OnSimCommand, &c);
  c.lcm.subscribe(channels::kDgRequest, &Impl::OnDgRequest, &c);
  c.lcm.subscribe(channels::kFootstepPlan, &Impl::OnFootstepPlan, &c);
  // Its own state, heard back: how far the receive path has got (SupervisorSilence).
  c.lcm.subscribe(channels::kRobotState, &Impl::OnOwnState, &c);
  std::thread lcm_thread(&Impl::LcmThread, &c);
  std::thread publisher(&Impl::PublisherThread, &c);
  if (c.camera) c.camera->Start();
  // The loop alone at the top priority, requested once the other threads exist (they would
  // inherit it): the LCM and publisher threads ask for kIoPriority themselves, the camera
  // thread runs at SCHED_IDLE.
  if (c.options.realtime) {
    const runtime::RealtimeStatus rt = runtime::RequestRealtime(kLoopPriority);
    runtime::LogLine("[controller] loop thread ", rt.message);
  } else {
    runtime::LogLine(
        "[controller] real-time scheduling not requested (--realtime): normal priority");
  }
  runtime::LogLine(
      "[controller] commands: ",
      c.verifier ? "signed only (key " + c.options.key_file + ")"
                 : std::string("unsigned (no key)"),
      "; supervisor timeout ",
      c.options.supervisor_timeout > 0.0
          ? std::to_string(static_cast<int>(std::lround(1e3 * c.options.supervisor_timeout))) +
                " ms"
          : std::string("off"));
  if (c.driver_lcm) c.driver_lcm->subscribe(channels::kDriverState, &Impl::OnDriverState, &c);
  runtime::LogLine("[controller] ", c.robot.name, " on ", c.options.backend, " backend, ",
                   c.model->nv, " dofs, graph of ", c.graph->entities().size(), " entities; ",
                   c.options.duration > 0.0 ? "running " + std::to_string(c.options.duration) + " s"
                                            : std::string("running until stopped"),
                   " at speed ", c.options.speed);

  // With a driver, its states set the pace (the clock only measures); else the clock does.
  const bool driven = c.driver_device != nullptr;
  runtime::LoopClock clock(kDt, driven ? 0.0 : c.options.speed);
  ReferenceWait reference_wait;
  const bool unpaced = c.options.speed == 0.0;
  graph::Tick t{0, 0.0, kDt};
  const int64_t last_tick = c.options.duration > 0.0 ? std::llround(c.options.duration / kDt) : -1;
  while (!c.stop && (last_tick < 0 || t.index < last_tick)) {
    if (driven && !c.WaitDriverState(c.options.driver_timeout)) continue;
    if (unpaced) reference_wait.Before(c, t);
    runtime::TickTiming timing = clock.WaitNextTick();
    c.LoopTick(t, clock);
    timing.compute_us = clock.ElapsedInTickUs();
    c.timings.Push(timing);
    ++t;
  }
  c.stop = true;
  // Give the publisher a last snapshot before everything stops.
  lcm_thread.join();
  publisher.join();
  if (c.camera) c.camera->Stop();
  runtime::LogLine("[controller] stopped after ", t.index, " ticks (", t.time, " s), ",
                   clock.deadline_misses(), " deadline misses");
  return 0;
}

// ---- command line -----------------------------------------------------------------------------

ControllerOptions ParseOptions(int argc, char** argv, bool* help, bool* describe_robot) {
  ControllerOptions o;
  if (const char* url = std::getenv("MARIONETTE_LCM_URL")) o.lcm_url = url;
  if (const char* key = std::getenv("MARIONETTE_KEY")) o.key_file = key;
  *help = false;
  *describe_robot = false;
  const auto value = [&](int& i) -> std::string {
    if (i + 1 >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs a value");
    return argv[++i];
  };
  const auto number = [&](int& i) -> double {
    const std::string flag = argv[i];
    return ParseNonNegative(flag, value(i));
  };
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "-h" || a == "--help")
      *help = true;
    else if (a == "--describe-robot")
      *describe_robot = true;
    else if (a == "--robot")
      o.robot = value(i);
    else if (a == "--backend")
      o.backend = value(i);
    else if (a == "--scene")
      o.scene = value(i);
    else if (a == "--encoder-offsets")
      o.encoder_offsets = ParseJointValues(a, value(i));
    else if (a == "--models")
      o.models_dir = value(i);
    else if (a == "--lcm-url")
      o.lcm_url = value(i);
    else if (a == "--realtime")
      o.realtime = true;
    else if (a == "--duration")
      o.duration = number(i);
    else if (a == "--speed")
      o.speed = number(i);
    else if (a == "--state-rate")
      o.state_rate = number(i);
    else if (a == "--status-rate")
      o.status_rate = number(i);
    else if (a == "--camera-rate")
      o.camera_rate = number(i);
    else if (a == "--camera-size")
      std::tie(o.camera_width, o.camera_height) = ParseImageSize(a, value(i));
    else if (a == "--camera-noise")
      o.camera_noise = number(i);
    else if (a == "--depth-noise")
      o.depth_noise = number(i);
    else if (a == "--velocity-scale")
      o.velocity_scale = number(i);
    else if (a == "--timing-log")
      o.timing_log = value(i);
    else if (a == "--no-profiling")
      o.profiling = false;
    else if (a == "--overrun-hold-ticks")
      o.overrun_hold_ticks = static_cast<int64_t>(number(i));
    else if (a == "--supervisor-timeout")
      o.supervisor_timeout = number(i);
    else if (a == "--key")
      o.key_file = value(i);
    else if (a == "--driver-timeout")
      o.driver_timeout = number(i);
    else if (a == "--journal")
      o.journal_file = value(i);
    else if (a == "-v" || a == "--verbose")
      o.verbose = true;
    else
      throw std::invalid_argument("unknown argument '" + a + "'");
  }
  if (o.robot.empty() && !*help)
    throw std::invalid_argument(
        "--robot NAME|DIR is required (`marionette robot list` shows the robots; docs/robots.md)");
  CheckLcmUrl(o.lcm_url);
  if (o.state_rate <= 0.0 || o.state_rate > 1000.0)
    throw std::invalid_argument("--state-rate must be in (0, 1000]");
  if (!o.encoder_offsets.empty() && o.backend != "mujoco") {
    throw std::invalid_argument("--encoder-offsets calibrates the mujoco backend's encoders; the " +
                                o.backend + " backend has none" +
                                (o.backend == "driver"
                                     ? " (the driver reads calibrated encoders: marionette-sim "
                                       "--encoder-offsets)"
                                     : ""));
  }
  if (o.driver_timeout <= 0.0) throw std::invalid_argument("--driver-timeout must be > 0");
  return o;
}

}  // namespace marionette::controller
