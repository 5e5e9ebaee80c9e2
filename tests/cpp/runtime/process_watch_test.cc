// Watching another process's exit: a child that is killed, one that exits by itself, a pid that
// is gone, and pids named in another namespace (never watched).
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <string>

#include "marionette/runtime/process_watch.h"

namespace marionette::runtime {
namespace {

// A child that sleeps until killed, or exits after `exit_after_ms` when >= 0.
pid_t Child(int exit_after_ms = -1) {
  const pid_t pid = fork();
  if (pid == 0) {
    usleep(static_cast<useconds_t>(1000 * (exit_after_ms >= 0 ? exit_after_ms : 60'000)));
    _exit(0);
  }
  return pid;
}

bool ReadableWithin(int fd, int ms) {
  pollfd p{fd, POLLIN, 0};
  return poll(&p, 1, ms) > 0 && (p.revents & POLLIN) != 0;
}

TEST(ProcessWatchTest, NamespaceNamesTheBootAndThePidNamespace) {
  const std::string& ns = ThisProcessNamespace();
  ASSERT_FALSE(ns.empty());
  EXPECT_NE(ns.find("/pid:["), std::string::npos) << ns;
  EXPECT_EQ(&ns, &ThisProcessNamespace());  // read once
}

TEST(ProcessWatchTest, AKilledProcessMakesTheDescriptorReadable) {
  const pid_t pid = Child();
  ProcessWatch watch;
  const ProcessWatch::Start start = watch.Watch(pid, ThisProcessNamespace());
  if (start == ProcessWatch::Start::kUnavailable) {
    kill(pid, SIGKILL);
    waitpid(pid, nullptr, 0);
    GTEST_SKIP() << "pidfds refused on this machine: " << watch.why_unavailable();
  }
  ASSERT_EQ(start, ProcessWatch::Start::kWatching);
  EXPECT_EQ(watch.pid(), pid);
  EXPECT_FALSE(watch.Exited());
  EXPECT_FALSE(ReadableWithin(watch.fd(), 50));
  EXPECT_EQ(watch.Watch(pid, ThisProcessNamespace()), ProcessWatch::Start::kWatching);  // kept
  kill(pid, SIGKILL);
  EXPECT_TRUE(ReadableWithin(watch.fd(), 5000));  // before it is reaped: exit, not reaping
  EXPECT_TRUE(watch.Exited());
  waitpid(pid, nullptr, 0);
  watch.Stop();
  EXPECT_EQ(watch.fd(), -1);
  EXPECT_FALSE(watch.Exited());
}

TEST(ProcessWatchTest, AProcessThatExitsByItselfIsSeenAndAGoneOneIsSaidGone) {
  const pid_t pid = Child(20);
  ProcessWatch watch;
  if (watch.Watch(pid, ThisProcessNamespace()) == ProcessWatch::Start::kUnavailable) {
    waitpid(pid, nullptr, 0);
    GTEST_SKIP() << watch.why_unavailable();
  }
  EXPECT_TRUE(ReadableWithin(watch.fd(), 5000));
  waitpid(pid, nullptr, 0);  // reaped: the pid no longer exists
  ProcessWatch again;
  EXPECT_EQ(again.Watch(pid, ThisProcessNamespace()), ProcessWatch::Start::kGone);
  EXPECT_EQ(again.fd(), -1);
}

TEST(ProcessWatchTest, APidOfAnotherMachineOrNamespaceIsNeverWatched) {
  ProcessWatch watch;
  const int self = static_cast<int>(getpid());
  for (const std::string& ns :
       {std::string(""), std::string("another-boot/pid:[1]"),
        ThisProcessNamespace().substr(0, ThisProcessNamespace().find('/')) + "/pid:[1]"}) {
    EXPECT_EQ(watch.Watch(self, ns), ProcessWatch::Start::kUnavailable) << ns;
    EXPECT_EQ(watch.fd(), -1);
  }
  EXPECT_EQ(watch.Watch(0, ThisProcessNamespace()), ProcessWatch::Start::kUnavailable);
  EXPECT_EQ(watch.Watch(-5, ThisProcessNamespace()), ProcessWatch::Start::kUnavailable);
}

TEST(ProcessWatchTest, AWatchMovesToTheNextProcessNamed) {
  const pid_t first = Child(), second = Child();
  ProcessWatch watch;
  if (watch.Watch(first, ThisProcessNamespace()) == ProcessWatch::Start::kUnavailable) {
    for (pid_t p : {first, second}) kill(p, SIGKILL), waitpid(p, nullptr, 0);
    GTEST_SKIP() << watch.why_unavailable();
  }
  ASSERT_EQ(watch.Watch(second, ThisProcessNamespace()), ProcessWatch::Start::kWatching);
  kill(first, SIGKILL);
  waitpid(first, nullptr, 0);
  EXPECT_FALSE(ReadableWithin(watch.fd(), 50));  // the first's exit is no longer watched
  kill(second, SIGKILL);
  EXPECT_TRUE(ReadableWithin(watch.fd(), 5000));
  waitpid(second, nullptr, 0);
}

}  // namespace
}  // namespace marionette::runtime
