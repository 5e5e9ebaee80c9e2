#include "marionette/runtime/process_watch.h"

#include <poll.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>

namespace marionette::runtime {
namespace {

std::string ReadNamespace() {
  std::ifstream boot("/proc/sys/kernel/random/boot_id");
  std::string boot_id;
  if (!std::getline(boot, boot_id) || boot_id.empty()) return "";
  char link[64] = {};
  const ssize_t n = readlink("/proc/self/ns/pid", link, sizeof(link) - 1);
  if (n <= 0) return "";
  return boot_id + "/" + std::string(link, static_cast<size_t>(n));
}

}  // namespace

const std::string& ThisProcessNamespace() {
  static const std::string kNamespace = ReadNamespace();
  return kNamespace;
}

ProcessWatch::~ProcessWatch() { Stop(); }

void ProcessWatch::Stop() {
  if (fd_ >= 0) close(fd_);
  fd_ = -1;
  pid_ = 0;
}

ProcessWatch::Start ProcessWatch::Watch(int pid, const std::string& pid_namespace) {
  if (pid == pid_ && fd_ >= 0) return Start::kWatching;
  Stop();
  if (pid <= 0 || pid_namespace.empty() || pid_namespace != ThisProcessNamespace()) {
    why_unavailable_ = "another machine or pid namespace";
    return Start::kUnavailable;
  }
#ifdef SYS_pidfd_open
  const long fd = syscall(SYS_pidfd_open, pid, 0);
  if (fd >= 0) {
    fd_ = static_cast<int>(fd);
    pid_ = pid;
    return Start::kWatching;
  }
  if (errno == ESRCH) return Start::kGone;
  why_unavailable_ = std::string("pidfd_open: ") + std::strerror(errno);
#else
  why_unavailable_ = "pidfd_open is not known to this system's headers";
#endif
  return Start::kUnavailable;
}

bool ProcessWatch::Exited() const {
  if (fd_ < 0) return false;
  pollfd p{fd_, POLLIN, 0};
  return poll(&p, 1, 0) > 0 && (p.revents & POLLIN) != 0;
}

}  // namespace marionette::runtime
