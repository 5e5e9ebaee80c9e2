#pragma once
/// Knowing the moment another process on this machine exits, without waiting for its silence.
///
/// A process names itself by its pid and the pid's namespace (ThisProcessNamespace: the kernel's
/// boot id and the pid namespace, so that a pid from another machine, another boot or another
/// container is never taken for one of ours). ProcessWatch opens a Linux pidfd on such a process:
/// the descriptor becomes readable when the process exits, so a poll() on it wakes at once.

#include <string>

namespace marionette::runtime {

/// "<boot id>/<pid namespace>" of this process, e.g. "6c1f…-…/pid:[4026531836]"; "" if /proc does
/// not tell (then no one can watch this process).
const std::string& ThisProcessNamespace();

class ProcessWatch {
 public:
  ProcessWatch() = default;
  ~ProcessWatch();
  ProcessWatch(const ProcessWatch&) = delete;
  ProcessWatch& operator=(const ProcessWatch&) = delete;

  enum class Start {
    kWatching,     ///< fd() becomes readable when the process exits
    kGone,         ///< no such process: it has exited already
    kUnavailable,  ///< elsewhere (another namespace), or pidfds refused here (old kernel, seccomp)
  };
  /// Watches `pid` of `pid_namespace` (ThisProcessNamespace of the sender), replacing any earlier
  /// watch; the same pid again keeps the watch. why_unavailable() says why on kUnavailable.
  Start Watch(int pid, const std::string& pid_namespace);
  void Stop();  ///< watches nothing

  int pid() const { return pid_; }  ///< 0 when watching nothing
  int fd() const { return fd_; }    ///< -1 when watching nothing
  /// Whether the watched process has exited (a non-blocking poll of fd()); false when watching
  /// nothing.
  bool Exited() const;
  const std::string& why_unavailable() const { return why_unavailable_; }

 private:
  int pid_ = 0;
  int fd_ = -1;
  std::string why_unavailable_;
};

}  // namespace marionette::runtime
