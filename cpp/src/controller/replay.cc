// Offline, deterministic replay of a recorded controller run (see replay.h).
#include "marionette/controller/replay.h"

#include <lcm/lcm-cpp.hpp>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <map>
#include <sstream>

#include "controller_impl.h"

namespace marionette::controller {

namespace {

struct RecordedCommand {
  std::vector<std::string> names;
  std::vector<double> position, velocity;
};

struct RecordedRun {
  std::string config;
  int64_t num_lost = 0;
  std::vector<JournalEntry> entries;            // in consumption order
  std::map<int64_t, std::string> messages;      // payload hash -> bytes
  std::map<int64_t, RecordedCommand> commands;  // tick -> ROBOT_COMMAND
};

int JournalChannelIndex(const std::string& channel) {
  for (int i = 0; i < static_cast<int>(std::size(kJournalChannels)); ++i) {
    if (channel == kJournalChannels[i]) return i;
  }
  return -1;
}

// What to take from a log: the journal and the inputs it names, the recorded commands, or both.
enum class Take { kJournal = 1, kCommands = 2, kAll = 3 };

void ReadLog(const std::string& path, Take take, RecordedRun* out,
             std::vector<std::string>* problems) {
  lcm::LogFile log(path, "r");
  if (!log.good()) throw std::runtime_error("cannot read the LCM log '" + path + "'");
  RecordedRun& run = *out;
  const bool journal = (static_cast<int>(take) & static_cast<int>(Take::kJournal)) != 0;
  const bool commands = (static_cast<int>(take) & static_cast<int>(Take::kCommands)) != 0;
  int64_t undecodable = 0;
  while (const lcm::LogEvent* event = log.readNextEvent()) {
    if (event->channel == channels::kControllerJournal) {
      if (!journal) continue;
      lcmt_controller_journal j;
      if (j.decode(event->data, 0, event->datalen) != event->datalen) {
        ++undecodable;
        continue;
      }
      if (run.config.empty()) run.config = j.config;
      run.num_lost = std::max(run.num_lost, j.num_lost);
      for (int i = 0; i < j.num_entries; ++i) {
        const int channel = JournalChannelIndex(j.channel[i]);
        if (channel < 0) {
          problems->push_back("journal names an unknown input '" + j.channel[i] + "'");
          continue;
        }
        run.entries.push_back(JournalEntry{j.tick[i], channel, j.payload_hash[i]});
      }
    } else if (event->channel == channels::kRobotCommand) {
      if (!commands) continue;
      lcmt_robot_command c;
      if (c.decode(event->data, 0, event->datalen) != event->datalen) {
        ++undecodable;
        continue;
      }
      run.commands[c.tick] = RecordedCommand{c.joint_name, c.joint_position, c.joint_velocity};
    } else if (JournalChannelIndex(event->channel) >= 0) {
      run.messages.emplace(Fnv1a(event->data, event->datalen),
                           std::string(static_cast<const char*>(event->data), event->datalen));
    }
  }
  if (undecodable > 0)
    problems->push_back(std::to_string(undecodable) + " undecodable journal/command messages in '" +
                        path + "' skipped");
  if (journal && run.config.empty()) {
    throw std::runtime_error(
        "'" + path + "' holds no CONTROLLER_JOURNAL: was the controller's journal recorded?");
  }
}

RecordedRun ReadRun(const ReplayOptions& options, std::vector<std::string>* problems) {
  RecordedRun run;
  if (options.journal.empty()) {
    ReadLog(options.log, Take::kAll, &run, problems);
  } else {
    ReadLog(options.journal, Take::kJournal, &run, problems);
    ReadLog(options.log, Take::kCommands, &run, problems);
  }
  // Consumption order is tick order; entries of one tick keep their recorded order.
  std::stable_sort(run.entries.begin(), run.entries.end(),
                   [](const JournalEntry& a, const JournalEntry& b) { return a.tick < b.tick; });
  return run;
}

ControllerOptions OptionsFromConfig(const std::string& config, const ReplayOptions& replay) {
  std::vector<std::string> words{"marionette-controller"};
  std::istringstream in(config);
  for (std::string w; in >> w;) words.push_back(w);
  std::vector<char*> argv;
  for (std::string& w : words) argv.push_back(w.data());
  bool help = false, describe = false;
  ControllerOptions o = ParseOptions(static_cast<int>(argv.size()), argv.data(), &help, &describe);
  o.lcm_url = "memq://";  // nothing goes out
  o.models_dir = replay.models_dir;
  if (!replay.scene.empty()) o.scene = replay.scene;
  o.camera_rate = 0.0;
  o.profiling = false;  // budgets are replayed from the journal
  o.speed = 0.0;
  o.key_file.clear();  // the journal names messages whose signatures the live run checked
  o.verbose = replay.verbose;
  return o;
}

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) < 0x20) {
      out += ' ';
      continue;
    }
    out += c;
  }
  return out;
}

}  // namespace

bool ReplayResult::ok() const {
  return problems.empty() && journal_mismatches == 0 && first_divergence_tick < 0 &&
         commands_compared > 0;
}

std::string ReplayResult::ToJson() const {
  std::ostringstream o;
  o.precision(17);
  o << "{\"ok\": " << (ok() ? "true" : "false") << ", \"config\": \"" << Escape(config)
    << "\", \"ticks\": " << ticks << ", \"inputs\": " << inputs
    << ", \"commands_compared\": " << commands_compared
    << ", \"max_difference\": " << max_difference
    << ", \"first_divergence_tick\": " << first_divergence_tick << ", \"first_divergence\": \""
    << Escape(first_divergence) << "\", \"journal_mismatches\": " << journal_mismatches
    << ", \"first_journal_mismatch\": \"" << Escape(first_journal_mismatch)
    << "\", \"problems\": [";
  for (size_t i = 0; i < problems.size(); ++i)
    o << (i ? ", " : "") << "\"" << Escape(problems[i]) << "\"";
  o << "]}";
  return o.str();
}

ReplayResult ReplayLog(const ReplayOptions& options) {
  ReplayResult result;
  const RecordedRun run = ReadRun(options, &result.problems);
  result.config = run.config;
  if (run.num_lost > 0) {
    result.problems.push_back(
        std::to_string(run.num_lost) +
        " journal entries were lost during the run (queue full): the replay cannot be exact");
  }
  const ControllerOptions controller_options = OptionsFromConfig(run.config, options);
  // Driver backend: the robot's first state is the journal's first DRIVER_STATE (tick 0's).
  std::string first_state;
  int64_t first_state_hash = 0;
  if (controller_options.backend == "driver") {
    for (const JournalEntry& e : run.entries) {
      if (e.channel != kDriverStateChannel) continue;
      const auto message = run.messages.find(e.hash);
      if (message == run.messages.end()) break;
      first_state = message->second;
      first_state_hash = e.hash;
      break;
    }
    if (first_state.empty())
      throw std::runtime_error("the log holds no DRIVER_STATE the controller took: cannot replay");
  }
  Controller::Impl c(controller_options, first_state.empty() ? nullptr : &first_state);
  c.replaying = true;
  std::map<std::string, int> joint_index;
  for (size_t i = 0; i < c.joint_names.size(); ++i)
    joint_index[c.joint_names[i]] = static_cast<int>(i);

  int64_t last_tick = run.commands.empty() ? -1 : run.commands.rbegin()->first;
  if (!run.entries.empty()) last_tick = std::max(last_tick, run.entries.back().tick);
  if (options.max_ticks >= 0) last_tick = std::min(last_tick, options.max_ticks - 1);
  runtime::LoopClock clock(kDt, 0.0);
  graph::Tick t{0, 0.0, kDt};
  size_t next_entry = 0;
  std::vector<std::pair<int, int64_t>> expected, replayed;  // (channel, hash) consumed at this tick
  // The configurations of the last ticks: a spec is built against the one its journal names.
  const Eigen::VectorXd initial_q = c.shared_q;
  constexpr int64_t kHistoryTicks = 10000;
  std::vector<Eigen::VectorXd> history(kHistoryTicks);
  for (; t.index <= last_tick; ++t) {
    // The journaled inputs of this tick, through the live decoding and validation.
    expected.clear();
    c.shared_q = c.q_kinematics->value();  // logs without build ticks: the best guess
    c.shared_tick = t.index - 1;
    c.shared_utime = TickUs(t);  // the clock references are checked against
    for (size_t k = next_entry; k < run.entries.size() && run.entries[k].tick == t.index; ++k) {
      const JournalEntry& e = run.entries[k];
      if (e.channel != kBuildTickChannel) continue;
      if (e.hash < 0) {
        c.shared_q = initial_q;
      } else if (e.hash < t.index && t.index - e.hash <= kHistoryTicks) {
        c.shared_q = history[e.hash % kHistoryTicks];
      } else {
        result.problems.push_back("the spec swapped at tick " + std::to_string(t.index) +
                                  " was built at tick " + std::to_string(e.hash) +
                                  ", beyond the replay's history");
      }
      c.shared_tick = e.hash;
    }
    for (; next_entry < run.entries.size() && run.entries[next_entry].tick == t.index;
         ++next_entry) {
      const JournalEntry& e = run.entries[next_entry];
      expected.emplace_back(e.channel, e.hash);
      ++result.inputs;
      if (e.channel == kBudgetHoldChannel) {
        c.replay_budget_hold = e.hash;
        continue;
      }
      if (e.channel == kSilenceHoldChannel) {
        c.replay_silence_hold = e.hash;
        continue;
      }
      if (e.channel == kBuildTickChannel) continue;  // applied above, before the spec is built
      if (e.channel == kDriverHoldChannel) {
        c.driver_hold = e.hash;
        continue;
      }
      // The first state was taken when the controller started.
      if (e.channel == kDriverStateChannel && t.index == 0 && e.hash == first_state_hash) continue;
      const auto message = run.messages.find(e.hash);
      if (message == run.messages.end()) {
        result.problems.push_back(std::string("the ") + kJournalChannels[e.channel] +
                                  " message consumed at tick " + std::to_string(t.index) +
                                  " is not in the log");
        continue;
      }
      lcm::ReceiveBuffer rbuf{const_cast<char*>(message->second.data()),
                              static_cast<uint32_t>(message->second.size()), 0};
      const std::string channel = kJournalChannels[e.channel];
      switch (e.channel) {
        case 0:
          c.OnSpec(&rbuf, channel);
          c.PostNextSpec();
          break;
        case 1:
          c.OnReference(&rbuf, channel);
          break;
        case 2:
          c.OnCommand(&rbuf, channel);
          break;
        case 3:
          c.OnSimCommand(&rbuf, channel);
          break;
        case 4:
          c.OnDgRequest(&rbuf, channel);
          c.ServeDg();
          break;
        case kFootstepPlanChannel:
          c.OnFootstepPlan(&rbuf, channel);
          break;
        case kDriverStateChannel:
          c.OnDriverState(&rbuf, channel);
          break;
      }
    }
    c.LoopTick(t, clock);
    history[t.index % kHistoryTicks] = c.q_kinematics->value();
    c.CollectSwitchDecision();
    c.CollectHoldController();
    c.ArmHoldController();  // as the LCM thread does once a swap is decided
    // Same inputs consumed at the same tick?
    replayed.clear();
    JournalEntry e;
    while (c.journal.Pop(&e)) replayed.emplace_back(e.channel, e.hash);
    std::sort(expected.begin(), expected.end());
    std::sort(replayed.begin(), replayed.end());
    if (expected != replayed) {
      if (result.journal_mismatches++ == 0) {
        result.first_journal_mismatch =
            "tick " + std::to_string(t.index) + ": recorded " + std::to_string(expected.size()) +
            " inputs consumed, replay " + std::to_string(replayed.size());
      }
    }
    // Same command?
    const auto recorded = run.commands.find(t.index);
    if (recorded == run.commands.end()) continue;
    ++result.commands_compared;
    const RecordedCommand& r = recorded->second;
    for (size_t i = 0; i < r.names.size() && i < r.position.size() && i < r.velocity.size(); ++i) {
      const auto j = joint_index.find(r.names[i]);
      if (j == joint_index.end()) {
        result.problems.push_back("ROBOT_COMMAND names joint '" + r.names[i] + "' that " +
                                  c.robot.name + " lacks");
        break;
      }
      const double q = c.loop_state.q_command[c.joint_q[j->second]];
      const double v = c.loop_state.v_command[c.joint_v[j->second]];
      for (const auto& [what, rec, rep] : {std::tuple{"joint_position", r.position[i], q},
                                           std::tuple{"joint_velocity", r.velocity[i], v}}) {
        const double d = std::abs(rec - rep);
        result.max_difference = std::max(result.max_difference, std::isfinite(d) ? d : INFINITY);
        if (!(d <= options.tolerance) && result.first_divergence_tick < 0) {
          result.first_divergence_tick = t.index;
          std::ostringstream s;
          s.precision(17);
          s << "ROBOT_COMMAND " << what << "[" << r.names[i] << "]: recorded " << rec
            << ", replayed " << rep;
          result.first_divergence = s.str();
        }
      }
    }
  }
  result.ticks = t.index;
  if (next_entry < run.entries.size() && options.max_ticks < 0) {
    result.problems.push_back(std::to_string(run.entries.size() - next_entry) +
                              " journal entries were not replayed");
  }
  return result;
}

}  // namespace marionette::controller
