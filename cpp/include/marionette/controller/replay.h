#pragma once
/// Deterministic replay of a recorded controller run.
///
/// The live controller journals every input its loop consumed with the tick that consumed it
/// (CONTROLLER_JOURNAL: channel + FNV-1a hash of the message bytes), plus the one decision it
/// takes from wall-clock timing (a hold for an overrun budget). With an LCM log of the run,
/// ReplayLog rebuilds the same controller (the journal carries the options that decide the
/// motion), runs the same 1 kHz loop offline on a simulated clock, hands each journaled
/// message to the same decoding/validation code just before the tick that consumed it, and
/// compares every recorded ROBOT_COMMAND (joint positions and velocities at its tick) with the
/// replayed one. MuJoCo is deterministic for the same model, initial state and controls, so
/// on the same build the match is exact; `max_difference` says how close it is elsewhere.

#include <cstdint>
#include <string>
#include <vector>

namespace marionette::controller {

struct ReplayOptions {
  std::string log;  ///< the LCM log of the live run
  /// The controller's own journal of the run (marionette-controller --journal): its inputs and
  /// journal are taken from it, the recorded commands from `log` ("" = everything from `log`)
  std::string journal;
  std::string models_dir;   ///< models/ of the repository
  std::string scene;        ///< overrides the journaled scene path ("" = the journal's)
  double tolerance = 1e-9;  ///< largest accepted |recorded - replayed| command difference
  int64_t max_ticks = -1;   ///< replay only the first ticks of the run (-1: all of it)
  bool verbose = false;
};

struct ReplayResult {
  std::string config;                  ///< the journaled controller options
  int64_t ticks = 0;                   ///< ticks replayed
  int64_t inputs = 0;                  ///< journaled inputs handed to the loop
  int64_t commands_compared = 0;       ///< recorded ROBOT_COMMAND messages compared
  double max_difference = 0.0;         ///< over every compared joint position and velocity
  int64_t first_divergence_tick = -1;  ///< first tick over tolerance (-1: none)
  std::string first_divergence;    ///< "ROBOT_COMMAND joint_position[arm_left_2_joint]: 0.1 vs 0.2"
  int64_t journal_mismatches = 0;  ///< inputs consumed at another tick than recorded
  std::string first_journal_mismatch;
  std::vector<std::string> problems;  ///< missing messages, lost journal entries...
  bool ok() const;
  std::string ToJson() const;
};

/// Throws std::runtime_error when the log cannot be read or holds no journal.
ReplayResult ReplayLog(const ReplayOptions& options);

}  // namespace marionette::controller
