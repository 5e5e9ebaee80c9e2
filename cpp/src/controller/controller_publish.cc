// marionette-controller's publisher thread: state, command, status, range finders and ground
// truth, from lock-free snapshots of the loop.
#include "controller_impl.h"

namespace marionette::controller {

// ---- publisher --------------------------------------------------------------------------------

void Controller::Impl::PublisherThread() {
  if (options.realtime) {
    runtime::LogLine("[controller] publisher thread ",
                     runtime::RequestThreadPriority(kIoPriority).message);
  }
  runtime::TimingWindow period(10000), compute(10000), lateness(10000);
  const auto state_period = std::chrono::duration<double>(1.0 / std::max(1.0, options.state_rate));
  const auto status_period =
      std::chrono::duration<double>(1.0 / std::max(0.1, options.status_rate));
  auto next_state = Clock::now(), next_status = Clock::now();
  runtime::TickTiming timing;
  int64_t last_tick = -1;
  std::vector<runtime::TickTiming> all;  // every tick, for --timing-log (off the loop)
  auto next_journal = Clock::now();
  bool first_journal = true;  // the first batch goes out even empty: it carries the config
  if (!options.timing_log.empty()) all.reserve(1 << 20);
  while (!stop) {
    std::this_thread::sleep_until(std::min(next_state, next_status));
    while (timings.Pop(&timing)) {
      period.Add(timing.period_us);
      compute.Add(timing.compute_us);
      lateness.Add(timing.lateness_us);
      if (!options.timing_log.empty()) all.push_back(timing);
    }
    RecordDriverStates();
    if (snapshots->Fetch()) {
      const Snapshot& fresh = snapshots->read_slot();
      std::lock_guard<std::mutex> lock(shared_mutex);
      shared_q = fresh.q_kinematics;
      shared_utime = fresh.utime;
      shared_tick = fresh.tick;
    }
    const Snapshot& s = snapshots->read_slot();
    const auto now = Clock::now();
    if (now >= next_state) {
      if (s.tick != last_tick) PublishState(s);
      if (s.tick != last_tick && s.walking) PublishWalkStatus(s);
      last_tick = s.tick;
      next_state += std::chrono::duration_cast<Clock::duration>(state_period);
      if (next_state < now) next_state = now;
    }
    if (now >= next_journal) {  // the inputs the loop consumed, batched at 10 Hz
      PublishJournal(s.utime, /*always=*/first_journal);
      first_journal = false;
      next_journal = now + std::chrono::milliseconds(100);
    }
    if (now >= next_status) {
      PublishStatus(s, period, compute, lateness);
      next_status += std::chrono::duration_cast<Clock::duration>(status_period);
      if (next_status < now) next_status = now;
    }
  }
  // The loop has stopped: the last consumed inputs go out before the process ends.
  snapshots->Fetch();
  PublishJournal(snapshots->read_slot().utime, false);
  if (!options.timing_log.empty()) {
    while (timings.Pop(&timing)) all.push_back(timing);
    if (FILE* f = std::fopen(options.timing_log.c_str(), "w")) {
      std::fprintf(f, "period_us,compute_us,lateness_us\n");
      for (const runtime::TickTiming& x : all) {
        std::fprintf(f, "%.3f,%.3f,%.3f\n", x.period_us, x.compute_us, x.lateness_us);
      }
      std::fclose(f);
    } else {
      runtime::LogLine("[controller] cannot write the timing log ", options.timing_log);
    }
  }
}

void Controller::Impl::RecordDriverStates() {
  if (!black_box || !state_records) return;
  const std::vector<uint8_t>* state = nullptr;
  while ((state = state_records->Front()) != nullptr) {
    Record(channels::kDriverState, state->data(), state->size(), WallUs());
    state_records->PopFront();
  }
}

void Controller::Impl::PublishJournal(int64_t utime, bool always) {
  lcmt_controller_journal j{};
  JournalEntry entry;
  while (journal.Pop(&entry)) {
    j.tick.push_back(entry.tick);
    j.channel.push_back(kJournalChannels[entry.channel]);
    j.payload_hash.push_back(entry.hash);
  }
  RecordDriverStates();  // the robot's states the loop took before this batch
  if (j.tick.empty() && !always) return;
  j.utime = utime;
  j.config = MotionConfig();
  j.num_lost =
      journal_lost.load(std::memory_order_relaxed) + records_lost.load(std::memory_order_relaxed);
  j.num_entries = static_cast<int32_t>(j.tick.size());
  lcm.publish(channels::kControllerJournal, &j);
  if (black_box) {
    std::vector<uint8_t> bytes(j.getEncodedSize());
    j.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
    Record(channels::kControllerJournal, bytes.data(), bytes.size(), WallUs());
  }
}

void Controller::Impl::PublishState(const Snapshot& s) {
  lcmt_robot_state state{};
  state.utime = s.utime;
  state.tick = s.tick;
  state.robot_name = robot.name;
  state.num_joints = static_cast<int32_t>(joint_names.size());
  state.joint_name = joint_names;
  lcmt_robot_command cmd{};
  cmd.utime = s.utime;
  cmd.tick = s.tick;
  cmd.num_joints = state.num_joints;
  cmd.joint_name = joint_names;
  for (size_t i = 0; i < joint_names.size(); ++i) {
    state.joint_position.push_back(s.q[joint_q[i]]);
    state.joint_velocity.push_back(s.v[joint_v[i]]);
    state.joint_effort.push_back(s.effort.size() ? s.effort[joint_v[i]] : 0.0);
    cmd.joint_position.push_back(s.q_command[joint_q[i]]);
    cmd.joint_velocity.push_back(s.v_command[joint_v[i]]);
  }
  state.base_quaternion[0] = 1.0;
  if (robot.base == "free_flyer") {
    const Eigen::Quaterniond quat(s.q[6], s.q[3], s.q[4], s.q[5]);
    const Eigen::Matrix3d R = quat.normalized().toRotationMatrix();
    const Eigen::Vector3d v_world = R * s.v.head<3>(), w_world = R * s.v.segment<3>(3);
    for (int k = 0; k < 3; ++k) {
      state.base_position[k] = s.q[k];
      state.base_linear_velocity[k] = v_world[k];
      state.base_angular_velocity[k] = w_world[k];
    }
    state.base_quaternion[0] = quat.w(), state.base_quaternion[1] = quat.x();
    state.base_quaternion[2] = quat.y(), state.base_quaternion[3] = quat.z();
  } else if (robot.base == "planar") {
    const double yaw = std::atan2(s.q[3], s.q[2]);
    state.base_position[0] = s.q[0], state.base_position[1] = s.q[1];
    state.base_quaternion[0] = std::cos(yaw / 2), state.base_quaternion[3] = std::sin(yaw / 2);
    state.base_linear_velocity[0] = std::cos(yaw) * s.v[0] - std::sin(yaw) * s.v[1];
    state.base_linear_velocity[1] = std::sin(yaw) * s.v[0] + std::cos(yaw) * s.v[1];
    state.base_angular_velocity[2] = s.v[2];
  }
  state.num_contacts = static_cast<int32_t>(s.wrenches.size() / 6);
  const std::vector<std::string> measured_bodies = robot.measured_bodies();  // soles, then fingers
  for (int i = 0; i < state.num_contacts; ++i) {
    state.contact_frame.push_back(measured_bodies[i]);
    state.contact_wrench.emplace_back(s.wrenches.begin() + 6 * i, s.wrenches.begin() + 6 * i + 6);
  }
  lcm.publish(channels::kRobotState, &state);
  lcm.publish(channels::kRobotCommand, &cmd);
  if (!free_objects.empty()) {
    const lcmt_object_poses poses = SimulatorObjectPoses(free_objects, s.object_poses, s.utime);
    lcm.publish(channels::kSimObjectPoses, &poses);
  }
  if (!range_finders.empty()) {
    const lcmt_range_finders ranges =
        RangeFinderReadings(robot.name, range_finders.names, s.range_distances, s.utime);
    lcm.publish(channels::kRangeFinders, &ranges);
  }
}

void Controller::Impl::PublishStatus(const Snapshot& s, runtime::TimingWindow& period,
                                     runtime::TimingWindow& compute,
                                     runtime::TimingWindow& lateness) {
  lcmt_controller_status st{};
  st.utime = s.utime;
  st.tick = s.tick;
  st.robot_name = robot.name;
  static const char* kModes[] = {"running", "holding", "estopped"};
  st.mode = kModes[std::clamp(s.mode, 0, 2)];
  std::lock_guard<std::mutex> lock(stats_mutex);
  const auto names = names_by_id.find(s.active_id);
  switch (s.reason) {
    case Reason::kStartup:
      st.mode_reason = "waiting for a controller spec";
      break;
    case Reason::kControllerAccepted:
      st.mode_reason = "controller accepted";
      break;
    case Reason::kCommand: {
      static const char* kCommandNames[] = {"none",  "hold",        "resume",
                                            "estop", "reset_estop", "stop"};
      st.mode_reason = std::string("command ") + kCommandNames[std::clamp(s.reason_index, 0, 5)];
      break;
    }
    case Reason::kWatchdog: {
      std::string task = "?";
      if (names != names_by_id.end() && s.reason_index >= 0 &&
          s.reason_index < static_cast<int>(names->second.streams.size())) {
        task = names->second.streams[s.reason_index];
      }
      char buffer[200];
      std::snprintf(buffer, sizeof(buffer),
                    "watchdog: reference of a streamed task (%s) stale for %.0f ms", task.c_str(),
                    1e3 * s.reason_value);
      st.mode_reason = buffer;
      break;
    }
    case Reason::kNonFinite:
      st.mode_reason = "the solver produced a non-finite velocity";
      break;
    case Reason::kSupervisorSilent: {
      char buffer[200];
      if (silence_exited_pid > 0) {
        std::snprintf(buffer, sizeof(buffer),
                      "supervisor exited: its process %d ended %.0f ms after its last message",
                      silence_exited_pid, 1e3 * s.reason_value);
      } else {
        std::snprintf(buffer, sizeof(buffer), "supervisor silent: nothing heard for %.0f ms",
                      1e3 * s.reason_value);
      }
      st.mode_reason = buffer;
      if (!silence_driver.empty()) st.mode_reason += " (last from '" + silence_driver + "')";
      st.mode_reason += s.active_id == kHoldControllerId && names != names_by_id.end()
                            ? "; the " + names->second.controller + " controller holds the robot"
                            : "; zero-velocity hold";
      break;
    }
    case Reason::kDriverSilent: {
      char buffer[200];
      std::snprintf(
          buffer, sizeof(buffer),
          "driver silent: no DRIVER_STATE for %.1f ms; holding until resumed or a new spec",
          1e3 * s.reason_value);
      st.mode_reason = buffer;
      break;
    }
    case Reason::kDriverRefused:
      st.mode_reason = "driver: a DRIVER_STATE was refused (" + last_driver_refusal +
                       "); holding until resumed or a new spec";
      break;
    case Reason::kBudget: {
      char buffer[200];
      std::snprintf(buffer, sizeof(buffer),
                    "time budget: entity #%d over its budget %.0f ticks in a row", s.reason_index,
                    s.reason_value);
      st.mode_reason = buffer;
      st.mode_reason += s.active_id == kHoldControllerId && names != names_by_id.end()
                            ? "; the " + names->second.controller + " controller holds the robot"
                            : "; zero-velocity hold";
      break;
    }
  }
  if (names != names_by_id.end()) {
    st.active_controller = names->second.controller;
    st.num_tasks = std::min<int>(s.num_tasks, static_cast<int>(names->second.tasks.size()));
    for (int i = 0; i < st.num_tasks; ++i) {
      st.task_name.push_back(names->second.tasks[i]);
      st.task_error_norm.push_back(s.task_error[i]);
    }
  }
  st.active_controller_id = s.active_id;
  st.realtime_factor = s.realtime_factor;
  const auto fill = [&](lcmt_timing_stats* out, runtime::TimingWindow& w) {
    const runtime::TimingSummary sum = w.Summarise();
    out->utime = s.utime;
    out->num_samples = sum.num_samples;
    out->p50_us = sum.p50, out->p99_us = sum.p99, out->max_us = sum.max, out->mean_us = sum.mean;
  };
  fill(&st.period, period);
  fill(&st.compute, compute);
  fill(&st.lateness, lateness);
  st.deadline_misses = s.deadline_misses;
  // Loop-side rejections join the LCM side's.
  std::map<std::string, int64_t> reasons = rejections;
  int64_t total = num_rejected;
  if (s.non_finite_ticks > 0) {
    reasons["SOLVER: non-finite velocity (ticks)"] = s.non_finite_ticks;
    total += s.non_finite_ticks;
  }
  st.num_rejected = total;
  st.num_reasons = static_cast<int32_t>(reasons.size());
  for (const auto& [reason, count] : reasons) {
    st.rejection_reason.push_back(reason);
    st.rejection_count.push_back(count);
  }
  st.last_rejection = last_rejection;
  st.num_switches = s.switches;
  st.num_refused_switches = s.refused_switches;
  if (pending_switch_tick >= 0 && s.tick >= pending_switch_tick) {
    last_switch_result = std::move(pending_switch_result);
    pending_switch_tick = -1;
  }
  st.last_switch_result = last_switch_result;
  lcm.publish(channels::kControllerStatus, &st);
}

}  // namespace marionette::controller
