#pragma once
/// When a controller may call its supervisor silent.
///
/// Times are when the kernel received the messages (LCM's recv_utime, wall clock [us]). LCM hands
/// the messages over in arrival order from a reader thread of its own, so a silence is measured
/// up to the arrival of the newest message handed over: what arrived before it, heartbeats
/// included, has been handled. "Now" is no evidence when nothing waits: LCM's reader thread may
/// itself be behind the kernel, kept off the CPU on a loaded machine. A plank-flip trial whose
/// supervisor beat at most 240 ms apart was held as silent for 1210 ms that way. The controller
/// therefore hears its own ROBOT_STATE back (state_rate, 100 Hz by default): on a bus that
/// flows, a message newer than the deadline comes within one state period. A receive path that
/// hands over nothing at all, not even that echo, for kReceiveStallFactor timeouts is itself the
/// silence: the controller cannot know its supervisor is there.

#include <cstdint>

namespace marionette::controller {

inline constexpr double kReceiveStallFactor = 4.0;

/// The silence to hold for [s], or 0 while the supervisor counts as heard. `last_heartbeat_us`:
/// the arrival of its last heartbeat; `newest_arrival_us`: of the newest message of any channel
/// handed over; `now_us`: the wall clock; `idle`: no message waits in LCM's queue.
inline double SupervisorSilence(int64_t last_heartbeat_us, int64_t newest_arrival_us,
                                int64_t now_us, bool idle, double timeout_s) {
  const double heard_silent = 1e-6 * static_cast<double>(newest_arrival_us - last_heartbeat_us);
  if (heard_silent >= timeout_s) return heard_silent;
  const double wall_silent = 1e-6 * static_cast<double>(now_us - last_heartbeat_us);
  if (idle && wall_silent >= kReceiveStallFactor * timeout_s) return wall_silent;
  return 0.0;
}

}  // namespace marionette::controller
