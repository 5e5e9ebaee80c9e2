// marionette-controller's LCM thread: every input decoded, validated (or rejected and counted),
// controllers built off the loop and handed over, streamed references routed to their streams.
#include <poll.h>

#include "controller_impl.h"
#include "marionette/controller/supervisor_silence.h"

namespace marionette::controller {

// ---- LCM thread --------------------------------------------------------------------------------

namespace {

// The graph's structure is read (controllers built, requests served) only while this thread
// holds the lease; the loop takes it for the few microseconds of engaging the hold controller.
class GraphReadLease {
 public:
  explicit GraphReadLease(std::atomic<int>& lease) : lease_(lease) {
    for (int free = 0; !lease_.compare_exchange_weak(free, 1, std::memory_order_acquire);
         free = 0) {
      std::this_thread::yield();
    }
  }
  ~GraphReadLease() { lease_.store(0, std::memory_order_release); }
  GraphReadLease(const GraphReadLease&) = delete;
  GraphReadLease& operator=(const GraphReadLease&) = delete;

 private:
  std::atomic<int>& lease_;
};

}  // namespace

void Controller::Impl::LcmThread() {
  if (options.realtime) {
    runtime::LogLine("[controller] LCM thread ",
                     runtime::RequestThreadPriority(kIoPriority).message);
  }
  while (!stop) {
    try {
      const bool waiting = WaitForMessage();
      {
        // What the loop decided while this thread waited (or was kept off the CPU) is taken in
        // before the message that came after it: a footstep plan sent on seeing the hold
        // controller engaged goes to the hold controller, which refuses it, not to the
        // controller it replaced. A replay collects at the end of each tick, in the same order.
        GraphReadLease lease(graph_lease);
        CollectSwitchDecision();
        CollectHoldController();
      }
      const bool idle = !(waiting && lcm.handle() == 0);
      WatchSupervisor(idle);
      CountDriverRefusals();
      GraphReadLease lease(graph_lease);
      service.CollectGarbage();
      ServeSamples();
      ServeDg();
      PublishTiming();
      PostNextSpec();
      // Building a humanoid's hold controller keeps this thread off the socket for 20-50 ms: not
      // while messages come in, nor in the first second (controller time) after a swap, when a
      // step's first chunks arrive just ahead of their start (a late chunk makes the stream skip
      // samples).
      if (idle && loop_utime() > last_decision_utime + 1'000'000) ArmHoldController();
    } catch (const std::exception& e) {  // counted, and the thread goes on serving
      Guarded("LCM_THREAD", [&] { Reject("LCM_THREAD", "internal error", e.what()); });
    } catch (...) {
      Guarded("LCM_THREAD", [&] { Reject("LCM_THREAD", "internal error", "unknown exception"); });
    }
  }
}

void Controller::Impl::CountDriverRefusals() {
  DriverRefusalEvent event;
  while (driver_refusals.Pop(&event)) {
    Reject(channels::kDriverState, event.category, event.detail);
    std::lock_guard<std::mutex> lock(stats_mutex);
    last_driver_refusal = event.category + ": " + event.detail;
  }
}

// ---- the supervisor's heartbeat ----------------------------------------------------------------

void Controller::Impl::Heard(const std::string& source, int64_t arrival_us) {
  last_heartbeat_us = std::max(last_heartbeat_us, arrival_us);
  newest_arrival_us = std::max(newest_arrival_us, arrival_us);
  if (!source.empty()) driver = source;
  silence_raised = false;
}

void Controller::Impl::OnOwnState(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  newest_arrival_us = std::max(newest_arrival_us, rbuf->recv_utime);
}

int Controller::Impl::WaitMs() {
  // Past the deadline, the wait is for the message that proves the silence (SupervisorSilence):
  // 1 ms, not a spin.
  if (options.supervisor_timeout <= 0.0 || active_owned_id < 0 || silence_raised) return 2;
  const double left_ms =
      1e3 * options.supervisor_timeout - 1e-3 * static_cast<double>(WallUs() - last_heartbeat_us);
  return std::clamp(static_cast<int>(std::ceil(left_ms)), 1, 2);
}

bool Controller::Impl::WaitForMessage() {
  pollfd ready[2] = {{lcm.getFileno(), POLLIN, 0}, {supervisor_process.fd(), POLLIN, 0}};
  const nfds_t watched = supervisor_process.fd() < 0 ? 1 : 2;
  if (poll(ready, watched, WaitMs()) <= 0) return false;
  if (watched == 2 && (ready[1].revents & (POLLIN | POLLHUP | POLLERR)) != 0) {
    const int pid = supervisor_process.pid();
    supervisor_process.Stop();  // its pidfd stays readable: watched once
    SupervisorExited(pid);
  }
  return (ready[0].revents & POLLIN) != 0;
}

void Controller::Impl::WatchSupervisor(bool idle) {
  // Only a supervisor's controller is watched (not the hold controller, nor before the first).
  if (options.supervisor_timeout <= 0.0 || active_owned_id < 0 || silence_raised) return;
  const double silent = SupervisorSilence(last_heartbeat_us, newest_arrival_us, WallUs(), idle,
                                          options.supervisor_timeout);
  if (silent > 0.0) RaiseSilence(silent, 0);
}

void Controller::Impl::WatchSupervisorProcess(const lcmt_command& heartbeat) {
  // A replay holds where the journal says; the recorded pid is not this run's.
  if (heartbeat.sender_pid <= 0 || options.supervisor_timeout <= 0.0 || replaying) return;
  switch (supervisor_process.Watch(heartbeat.sender_pid, heartbeat.sender_pid_namespace)) {
    case runtime::ProcessWatch::Start::kWatching:
      return;
    case runtime::ProcessWatch::Start::kGone:  // it died while its last beat was on the way
      SupervisorExited(heartbeat.sender_pid);
      return;
    case runtime::ProcessWatch::Start::kUnavailable:
      if (options.verbose && !process_watch_noted) {
        runtime::LogLine("[controller] supervisor process ", heartbeat.sender_pid, " of '",
                         heartbeat.source, "' not watched (", supervisor_process.why_unavailable(),
                         "): its silence is noticed after --supervisor-timeout");
      }
      process_watch_noted = true;
      return;
  }
}

void Controller::Impl::SupervisorExited(int pid) {
  // Only a supervisor's controller is held (not the hold controller, nor before the first).
  if (options.supervisor_timeout <= 0.0 || active_owned_id < 0 || silence_raised) return;
  RaiseSilence(1e-6 * static_cast<double>(WallUs() - last_heartbeat_us), pid);
}

void Controller::Impl::RaiseSilence(double silent_s, int exited_pid) {
  silence_raised = true;
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    silence_driver = driver;
    silence_exited_pid = exited_pid;
  }
  silence_seconds.store(silent_s, std::memory_order_relaxed);
  silence_request.store(true, std::memory_order_release);
  if (!options.verbose) return;
  if (exited_pid > 0) {
    runtime::LogLine("[controller] supervisor process ", exited_pid, " exited (last heard: '",
                     driver, "', ", 1e3 * silent_s, " ms before): holding");
  } else {
    runtime::LogLine("[controller] supervisor silent for ", 1e3 * silent_s, " ms (last heard: '",
                     driver, "'): holding");
  }
}

void Controller::Impl::OnSpec(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  Guarded(channels::kControllerSpec, [&] {
    lcmt_controller_spec spec;
    if (!Admit(channels::kControllerSpec, rbuf, &spec)) return;
    Heard("", rbuf->recv_utime);
    if (waiting_specs.size() >= 8) {
      Reject(channels::kControllerSpec, "queue full",
             "controller '" + spec.name + "' dropped: 8 specs waiting");
      return;
    }
    waiting_specs.emplace_back(std::move(spec), Fnv1a(rbuf->data, rbuf->data_size));
  });
}

void Controller::Impl::PostNextSpec() {
  if (waiting_specs.empty() ||
      switch_state.load(std::memory_order_acquire) != static_cast<int>(SwitchState::kNone)) {
    return;
  }
  // The armed hold controller replaces the running controller: disarm it (a new one is built
  // for the new controller once its swap is decided).
  int armed = kHoldArmed;
  if (hold_state.compare_exchange_strong(armed, kHoldEmpty, std::memory_order_acq_rel))
    hold_controller.reset();
  CollectHoldController();  // engaged just now: the new controller replaces the hold controller
  const lcmt_controller_spec spec = std::move(waiting_specs.front().first);
  const int64_t spec_hash = waiting_specs.front().second;
  waiting_specs.pop_front();
  if (controllers.count(spec.controller_id) > 0) {
    Reject(channels::kControllerSpec, "duplicate id",
           "controller id " + std::to_string(spec.controller_id) + " is already in use");
    return;
  }
  // A recent configuration to check the spec against (its holds take the swap tick's values).
  Eigen::VectorXd q;
  int64_t build_tick = -1;
  {
    std::lock_guard<std::mutex> lock(shared_mutex);
    q = shared_q;
    build_tick = shared_tick;
  }
  // The running controller's entities go, the hold controller's too when it is the one running.
  std::vector<std::string> previous;
  if (controllers.count(active_owned_id) > 0)
    previous = controllers.at(active_owned_id)->entity_names;
  std::unique_ptr<BuiltController> built;
  try {
    built = factory->Build(spec, *graph, previous, q);
  } catch (const std::exception& e) {
    Reject(channels::kControllerSpec, "invalid spec", e.what());
    return;
  }
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    Names& names = names_by_id[built->id];
    names.controller = built->name;
    names.tasks = built->task_names;
    for (const auto& [task, stream] : built->streams) names.streams.push_back(task);
  }
  posted = built.get();
  posted_hash = spec_hash;
  posted_build_tick = build_tick;
  controllers[built->id] = std::move(built);
  switch_state.store(static_cast<int>(SwitchState::kPosted), std::memory_order_release);
}

void Controller::Impl::ArmHoldController() {
  if (hold_state.load(std::memory_order_acquire) != kHoldEmpty || !waiting_specs.empty() ||
      switch_state.load(std::memory_order_acquire) != static_cast<int>(SwitchState::kNone) ||
      active_owned_id < 0 || active_owned_id == kHoldControllerId ||
      active_owned_id == hold_unbuildable_for) {
    return;
  }
  Eigen::VectorXd q;
  {
    std::lock_guard<std::mutex> lock(shared_mutex);
    q = shared_q;
  }
  const auto start = Clock::now();
  try {
    hold_controller =
        BuildHoldController(*factory, *graph, *controllers.at(active_owned_id), q, model, soles);
  } catch (const std::exception& e) {  // reported once per controller; overruns then hold still
    hold_unbuildable_for = active_owned_id;
    Reject(channels::kControllerSpec, "hold controller", e.what());
    return;
  }
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    Names& names = names_by_id[kHoldControllerId];
    names = Names{hold_controller->name, hold_controller->task_names, {}};
  }
  armed_hold = hold_controller.get();
  hold_state.store(kHoldArmed, std::memory_order_release);
  if (options.verbose) {
    runtime::LogLine("[controller] hold controller '", hold_controller->name,
                     "' armed for controller ", active_owned_id, " in ",
                     std::chrono::duration<double, std::milli>(Clock::now() - start).count(),
                     " ms");
  }
}

void Controller::Impl::CollectHoldController() {
  const int state = hold_state.load(std::memory_order_acquire);
  if (state == kHoldStale) {
    hold_controller.reset();
    hold_state.store(kHoldEmpty, std::memory_order_release);
    return;
  }
  if (state != kHoldEngaged) return;
  // As for a swap: the edit holds the replaced topology, freed here with its controller.
  hold_controller->edit.reset();
  if (active_owned_id >= 0) controllers.erase(active_owned_id);
  active_owned_id = kHoldControllerId;
  const std::string result =
      "engaged the hold controller '" + hold_controller->name + "' (id " +
      std::to_string(kHoldControllerId) +
      (hold_engaged_why == Reason::kSupervisorSilent ? "): supervisor silent"
                                                     : "): time budget overrun");
  controllers[kHoldControllerId] = std::move(hold_controller);
  armed_hold = nullptr;
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    pending_switch_result = result;
    pending_switch_tick = hold_engaged_tick;
  }
  if (options.verbose) runtime::LogLine("[controller] ", result);
  last_decision_utime = hold_engaged_tick * 1000;
  hold_state.store(kHoldEmpty, std::memory_order_release);
}

std::string Controller::Impl::JumpedJoint() const {
  for (size_t k = 0; k < joint_v.size(); ++k) {
    if (joint_v[k] == refused_jump_v) return " (" + joint_names[k] + ")";
  }
  return "";
}

void Controller::Impl::CollectSwitchDecision() {
  const auto state = static_cast<SwitchState>(switch_state.load(std::memory_order_acquire));
  if (state != SwitchState::kApplied && state != SwitchState::kRefused) return;
  const int64_t id = posted->id;
  std::string result;
  if (state == SwitchState::kApplied) {
    // The edit now holds the previous topology: free it here, off the loop, with the previous
    // controller's bookkeeping.
    posted->edit.reset();
    controllers.erase(active_owned_id);  // the hold controller too: the next one is built anew
    active_owned_id = id;
    Heard("", WallUs());  // the watch on its supervisor starts with the controller
    result = "accepted controller '" + posted->name + "' (id " + std::to_string(id) + ")";
  } else {
    char jump[64];
    std::snprintf(jump, sizeof(jump), "%.4g", refused_jump);
    result = refused_jump < 0.0
                 ? "refused controller '" + posted->name + "' (id " + std::to_string(id) +
                       "): estop is latched"
                 : "refused controller '" + posted->name + "' (id " + std::to_string(id) +
                       "): command jump " + jump + " rad/s" + JumpedJoint() + " > " +
                       std::to_string(posted->max_switch_velocity_jump);
    Reject(channels::kControllerSpec, "discontinuous switch", result);
    controllers.erase(id);
  }
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    pending_switch_result = result;
    pending_switch_tick = decided_tick;
  }
  if (options.verbose) runtime::LogLine("[controller] ", result);
  last_decision_utime = decided_tick * 1000;
  posted = nullptr;
  switch_state.store(static_cast<int>(SwitchState::kNone), std::memory_order_release);
}

void Controller::Impl::OnReference(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  Guarded(channels::kTaskReference, [&] { ReceiveReference(rbuf); });
}

void Controller::Impl::ReceiveReference(const lcm::ReceiveBuffer* rbuf) {
  lcmt_task_reference msg;
  if (!Admit(channels::kTaskReference, rbuf, &msg)) return;
  auto it = controllers.find(msg.controller_id);
  if (it == controllers.end()) {
    Reject(
        channels::kTaskReference, "unknown controller",
        "task '" + msg.task_name + "': no controller with id " + std::to_string(msg.controller_id));
    return;
  }
  auto stream = it->second->streams.find(msg.task_name);
  if (stream == it->second->streams.end()) {
    Reject(channels::kTaskReference, "unknown task",
           "controller " + std::to_string(msg.controller_id) + " has no streamed task '" +
               msg.task_name + "'");
    return;
  }
  ReferenceStream& s = *stream->second;
  if (msg.num_samples < 1 || msg.value_size != s.value_size() ||
      (msg.derivative_size != 0 && msg.derivative_size != s.derivative_size()) ||
      static_cast<int>(msg.value.size()) != msg.num_samples ||
      static_cast<int>(msg.derivative.size()) != msg.num_samples) {
    Reject(channels::kTaskReference, "wrong size",
           "task '" + msg.task_name + "': " + std::to_string(msg.num_samples) + " samples of " +
               std::to_string(msg.value_size) + " values, the stream takes " +
               std::to_string(s.value_size()));
    return;
  }
  ReferenceChunk chunk;
  chunk.start_us = msg.utime;
  chunk.dt_us = msg.dt_us;
  chunk.num_samples = msg.num_samples;
  chunk.last = msg.last_chunk;
  chunk.sequence = msg.sequence;
  chunk.source_hash = Fnv1a(rbuf->data, rbuf->data_size);
  chunk.values.reserve(static_cast<size_t>(msg.num_samples) * s.value_size());
  chunk.derivatives.assign(static_cast<size_t>(msg.num_samples) * s.derivative_size(), 0.0);
  for (int i = 0; i < msg.num_samples; ++i) {
    if (static_cast<int>(msg.value[i].size()) != s.value_size() ||
        static_cast<int>(msg.derivative[i].size()) != msg.derivative_size) {
      Reject(channels::kTaskReference, "wrong size",
             "task '" + msg.task_name + "': ragged sample " + std::to_string(i));
      return;
    }
    chunk.values.insert(chunk.values.end(), msg.value[i].begin(), msg.value[i].end());
    if (msg.derivative_size != 0) {
      std::copy(msg.derivative[i].begin(), msg.derivative[i].end(),
                chunk.derivatives.begin() + static_cast<size_t>(i) * s.derivative_size());
    }
  }
  const std::string problem = s.ValidateChunk(chunk);
  if (!problem.empty()) {
    Reject(channels::kTaskReference, "invalid samples", "task '" + msg.task_name + "': " + problem);
    return;
  }
  if (!s.Push(chunk)) {
    Reject(channels::kTaskReference, "queue full", "task '" + msg.task_name + "': chunk dropped");
    return;
  }
  Heard("", rbuf->recv_utime);  // the stream itself is a heartbeat
}

void Controller::Impl::OnCommand(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  Guarded(channels::kCommand, [&] { ReceiveCommand(rbuf); });
}

void Controller::Impl::ReceiveCommand(const lcm::ReceiveBuffer* rbuf) {
  lcmt_command msg;
  if (!Admit(channels::kCommand, rbuf, &msg)) return;
  if (ToLower(msg.command) == "heartbeat") {  // the supervisor is alive; nothing for the loop
    Heard(msg.source.empty() ? "?" : msg.source, rbuf->recv_utime);
    WatchSupervisorProcess(msg);
    return;
  }
  static const std::map<std::string, Command> kCommands = {{"hold", Command::kHold},
                                                           {"resume", Command::kResume},
                                                           {"start", Command::kResume},
                                                           {"estop", Command::kEstop},
                                                           {"reset_estop", Command::kResetEstop},
                                                           {"stop", Command::kStop}};
  const auto it = kCommands.find(ToLower(msg.command));
  if (it == kCommands.end()) {
    Reject(channels::kCommand, "unknown command",
           "'" + msg.command + "' (hold, resume, start, estop, reset_estop, stop, heartbeat)");
    return;
  }
  Heard(msg.source.empty() ? "?" : msg.source, rbuf->recv_utime);
  // An estop must never be overwritten by a later, milder request before the loop saw it.
  command_hash.store(Fnv1a(rbuf->data, rbuf->data_size), std::memory_order_release);
  int expected = command_request.load();
  while (expected != static_cast<int>(Command::kEstop) &&
         !command_request.compare_exchange_weak(expected, static_cast<int>(it->second))) {
  }
  if (options.verbose) runtime::LogLine("[controller] command ", msg.command, " from ", msg.source);
}

void Controller::Impl::OnSimCommand(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  Guarded(channels::kSimCommand, [&] { ReceiveSimCommand(rbuf); });
}

void Controller::Impl::ReceiveSimCommand(const lcm::ReceiveBuffer* rbuf) {
  lcmt_sim_command msg;
  if (!Admit(channels::kSimCommand, rbuf, &msg)) return;
  if (!scene) {
    Reject(channels::kSimCommand, "no simulator", "the kinematic backend has no objects");
    return;
  }
  auto read = ReadSimCommand(msg, *scene, free_objects, free_object_ids);
  if (const auto* refusal = std::get_if<SimCommandRefusal>(&read)) {
    Reject(channels::kSimCommand, refusal->category, refusal->detail);
    return;
  }
  SimRequest r = std::get<SimRequest>(read);
  r.hash = Fnv1a(rbuf->data, rbuf->data_size);
  if (!sim_requests.Push(r)) {
    Reject(channels::kSimCommand, "queue full", "'" + msg.object_name + "' not changed");
  }
}

// ---- per-entity timing and budgets ----------------------------------------------------------

void Controller::Impl::PublishTiming() {
  // Entity names are read from the graph: only while the structure is frozen, and only for the
  // version the loop measured.
  const bool frozen =
      switch_state.load(std::memory_order_acquire) == static_cast<int>(SwitchState::kNone);
  std::pair<int64_t, int> event;
  while (frozen && overrun_events.Pop(&event)) {
    const auto& entities = graph->entities();
    if (event.second >= static_cast<int>(entities.size())) continue;
    const graph::Entity& e = *entities[event.second];
    lcmt_supervisor_event msg{};
    msg.utime = event.first * 1000;
    msg.name = "budget_overrun";
    msg.source = "controller";
    msg.detail = e.name() + " (" + e.type_name() + ") over its " +
                 std::to_string(e.time_budget_us()) + " us budget";
    msg.value = e.time_budget_us();
    lcm.publish(channels::kSupervisorEvent, &msg);
  }
  if (!frozen || !timing_tables->Fetch()) return;
  const TimingTable& table = timing_tables->read_slot();
  const auto& entities = graph->entities();
  if (table.graph_version != graph->version()) return;  // measured before the last swap
  lcmt_entity_timings msg{};
  msg.utime = table.utime;
  msg.window_ticks = table.window_ticks;
  msg.num_entities = std::min<int>(table.num_entities, static_cast<int>(entities.size()));
  for (int i = 0; i < msg.num_entities; ++i) {
    msg.entity.push_back(entities[i]->name());
    msg.type_name.push_back(entities[i]->type_name());
    msg.p50_us.push_back(1e-3 * table.windows[i].Quantile(0.50));
    msg.p99_us.push_back(1e-3 * table.windows[i].Quantile(0.99));
    msg.max_us.push_back(1e-3 * table.windows[i].max_ns);
    msg.budget_us.push_back(table.budget_us[i]);
    msg.overruns.push_back(table.overruns[i]);
  }
  lcm.publish(channels::kControllerTiming, &msg);
  last_timing = std::move(msg);
}

std::string Controller::Impl::TimingText() {
  if (last_timing.num_entities == 0)
    return "no timing yet (profiling off, or less than one window)\n";
  std::ostringstream os;
  os.setf(std::ios::fixed);
  os.precision(1);
  os << "entity self time per tick over the last " << last_timing.window_ticks << " ticks [us]\n";
  os << "  p50      p99      max   budget  overruns  entity\n";
  for (int i = 0; i < last_timing.num_entities; ++i) {
    char line[256];
    std::snprintf(line, sizeof(line), "%7.1f  %7.1f  %7.1f  %7.1f  %8lld  %s (%s)\n",
                  last_timing.p50_us[i], last_timing.p99_us[i], last_timing.max_us[i],
                  last_timing.budget_us[i], static_cast<long long>(last_timing.overruns[i]),
                  last_timing.entity[i].c_str(), last_timing.type_name[i].c_str());
    os << line;
  }
  return os.str();
}

// ---- introspection (DG_REQUEST) ----------------------------------------------------------

void Controller::Impl::OnDgRequest(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  Guarded(channels::kDgRequest, [&] {
    lcmt_dg_request request;
    if (!Admit(channels::kDgRequest, rbuf, &request)) return;
    if (waiting_dg.size() >= 64) {
      Reject(channels::kDgRequest, "queue full",
             "request " + std::to_string(request.request_id) + " dropped");
      return;
    }
    dg_hashes.push_back(Fnv1a(rbuf->data, rbuf->data_size));
    waiting_dg.push_back(std::move(request));
  });
}

void Controller::Impl::ServeDg() {
  // The structure is read here only while no swap is pending (the loop applies a swap this
  // thread posted) and under the graph lease (the loop engages the hold controller).
  while (!waiting_dg.empty() &&
         switch_state.load(std::memory_order_acquire) == static_cast<int>(SwitchState::kNone)) {
    const lcmt_dg_request request = std::move(waiting_dg.front());
    current_dg_hash = dg_hashes.front();
    waiting_dg.pop_front();
    dg_hashes.pop_front();
    Guarded(channels::kDgRequest, [&] { ServeDgRequest(request); });
  }
}

void Controller::Impl::ReplyDg(const lcmt_dg_request& request, bool ok, const std::string& error,
                               const std::string& text) {
  lcmt_dg_reply reply{};
  reply.utime = loop_utime();
  reply.request_id = request.request_id;
  reply.client = request.client;
  reply.ok = ok;
  reply.error = error;
  reply.text = text;
  lcm.publish(channels::kDgReply, &reply);
  // Counted under the command when it is one (a finite set of reasons, whatever is sent).
  static const std::set<std::string> kDgCommands = {"ls",      "get",   "set",    "trace",
                                                    "untrace", "graph", "timing", "budget"};
  if (!ok) {
    Reject(channels::kDgRequest,
           kDgCommands.count(request.command) ? "refused " + request.command : "unknown command",
           error);
  }
}

void Controller::Impl::ServeDgRequest(const lcmt_dg_request& request) {
  const std::string& command = request.command;
  if (request.num_signals != static_cast<int>(request.signal.size()) ||
      request.num_values != static_cast<int>(request.value.size())) {
    ReplyDg(request, false, "array sizes disagree with their num_ fields");
    return;
  }
  if (command == "ls") {
    ReplyDg(request, true, "", ListGraph(*graph));
  } else if (command == "graph") {
    ReplyDg(request, true, "", graph->ToDot());
  } else if (command == "timing") {
    ReplyDg(request, true, "", TimingText());
  } else if (command == "budget") {
    // signal[0] = entity, value[0] = budget [us] (0 removes it). Set between ticks: a plain
    // double written here and read by the loop — the worst a race does is one tick's check.
    if (request.num_signals != 1 || request.num_values != 1 || !(request.value[0] >= 0.0)) {
      ReplyDg(request, false, "budget takes one entity and one non-negative value [us]");
      return;
    }
    graph::Entity* e = graph->FindEntity(request.signal[0]);
    if (e == nullptr) {
      ReplyDg(request, false, "no entity '" + request.signal[0] + "'");
      return;
    }
    e->set_time_budget_us(request.value[0]);
    ReplyDg(request, true, "",
            "budget of " + e->name() + ": " + std::to_string(request.value[0]) + " us");
  } else if (command == "get" || command == "trace") {
    std::vector<std::string> names;
    for (const std::string& n : request.signal) {
      if (graph->FindSignal(n) == nullptr) {
        try {
          graph->signal(n);  // throws with the list of what exists
        } catch (const graph::GraphError& e) {
          ReplyDg(request, false, e.what());
          return;
        }
      }
      names.push_back(n);
    }
    if (names.empty()) {
      ReplyDg(request, false, command + " needs at least one signal");
      return;
    }
    if (command == "get") {
      gets.push_back(PendingGet{request.request_id, request.client, names});
    } else {
      if (!(request.rate > 0.0 && request.rate <= 1000.0)) {
        ReplyDg(request, false, "trace rate must be in (0, 1000] Hz");
        return;
      }
      trace = Trace{request.request_id, request.client, names,
                    std::max<int64_t>(1, std::llround(1.0 / (request.rate * kDt))), 0};
      ReplyDg(request, true, "",
              "tracing " + std::to_string(names.size()) + " signals on " + channels::kDgTrace);
    }
    UpdateWatch();
  } else if (command == "untrace") {
    trace = Trace{};
    UpdateWatch();
    ReplyDg(request, true, "", "trace stopped");
  } else if (command == "set") {
    if (request.num_signals != 1) {
      ReplyDg(request, false, "set takes one signal");
      return;
    }
    graph::SignalBase* signal = graph->FindSignal(request.signal[0]);
    if (signal == nullptr) {
      ReplyDg(request, false, "no signal '" + request.signal[0] + "'");
      return;
    }
    const std::string problem = service.QueueSet(*signal, request.value, current_dg_hash);
    if (problem.empty()) {
      ReplyDg(request, true, "", signal->full_name() + " set");
    } else {
      ReplyDg(request, false, problem);
    }
  } else {
    ReplyDg(
        request, false,
        "unknown command '" + command + "' (ls, get, set, trace, untrace, graph, timing, budget)");
  }
}

void Controller::Impl::UpdateWatch() {
  // One watch: the trace's signals and every pending get's, without duplicates.
  std::vector<std::string> names = trace.names;
  for (const PendingGet& g : gets) {
    for (const std::string& n : g.names) {
      if (std::find(names.begin(), names.end(), n) == names.end()) names.push_back(n);
    }
  }
  std::vector<graph::SignalBase*> signals;
  std::vector<std::string> kept;
  for (const std::string& n : names) {
    if (graph::SignalBase* s = graph->FindSignal(n)) {
      signals.push_back(s);
      kept.push_back(n);
    }
  }
  watch_names = kept;
  watch_id = service.SetWatch(signals);
}

void Controller::Impl::ServeSamples() {
  while (const WatchSample* sample = service.FrontSample()) {
    const Watch* watch = service.FindWatch(sample->watch_id);
    if (watch != nullptr && sample->watch_id == watch_id) {
      const auto reply_for = [&](const std::vector<std::string>& names, int64_t request_id,
                                 const std::string& client) {
        lcmt_dg_reply reply{};
        reply.utime = sample->utime;
        reply.tick = sample->tick;
        reply.request_id = request_id;
        reply.client = client;
        reply.ok = true;
        for (const std::string& n : names) {
          const auto it = std::find(watch_names.begin(), watch_names.end(), n);
          if (it == watch_names.end()) continue;
          const size_t i = it - watch_names.begin();
          const graph::SignalBase* s = watch->signals[i];
          const graph::Shape shape = s->shape();
          reply.signal.push_back(n);
          reply.type_name.push_back(s->type_name());
          reply.rows.push_back(shape.rows);
          reply.cols.push_back(shape.cols);
          reply.value.insert(reply.value.end(), sample->values.begin() + watch->offsets[i],
                             sample->values.begin() + watch->offsets[i] + shape.size());
        }
        reply.num_signals = static_cast<int32_t>(reply.signal.size());
        reply.num_values = static_cast<int32_t>(reply.value.size());
        return reply;
      };
      if (!gets.empty()) {
        for (const PendingGet& g : gets) {
          lcmt_dg_reply reply = reply_for(g.names, g.request_id, g.client);
          lcm.publish(channels::kDgReply, &reply);
        }
        gets.clear();
        UpdateWatch();
      }
      if (trace.request_id >= 0 && sample->tick >= trace.next_tick) {
        lcmt_dg_reply reply = reply_for(trace.names, trace.request_id, trace.client);
        lcm.publish(channels::kDgTrace, &reply);
        trace.next_tick = sample->tick + trace.period_ticks;
      }
    }
    service.PopSample();
  }
}

}  // namespace marionette::controller
