#pragma once
/// Hearing the request to stop, whatever the parent left this process with.
///
/// A process group, a terminal or `kill` asks a marionette program to stop with SIGINT or
/// SIGTERM, and the program then ends cleanly (its journal and logs written out). A signal mask
/// and ignored signals survive fork and exec, so a program started by a parent that blocked or
/// ignored them does not hear that request: a Ray worker blocks SIGINT, a non-interactive shell
/// ignores SIGINT in `command &`. Such a program was killed after its group's grace period
/// (5 s per process, which doubled the time of a trial on a Ray cluster) and lost what it had
/// not written yet.

namespace marionette::runtime {

/// Unblocks SIGINT and SIGTERM in the calling thread and gives any of them that is ignored its
/// default action back. Call first in main(): threads started later inherit the mask; install
/// handlers afterwards.
void RestoreStopSignals();

}  // namespace marionette::runtime
